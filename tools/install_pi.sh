#!/usr/bin/env bash
# Install the star tracker on a fresh Raspberry Pi OS Bookworm (64-bit) on a Pi 5:
#   sudo tools/install_pi.sh            (from a clone of this repository)
# Idempotent: running it again only brings things up to date. It
#   1. installs apt packages (venv, tools) and python3-picamera2 PINNED to a version
#      that works with Arducam's libcamera 0.3.x (0.3.20 .. 0.3.25, the newest the
#      archive holds; PICAMERA2_VERSION=<apt version> chooses another, e.g. with a
#      stock libcamera >= 0.5), then holds it so `apt upgrade` cannot break the pair;
#   2. copies the repository to /opt/startracker and makes a venv there with
#      --system-site-packages (so it sees python3-picamera2 and libcamera), with
#      numpy<2 and opencv-python-headless==4.11.0.86 (docs/pi5.md), and
#      pytest, for the on-device tests (README "On-device checks");
#   3. creates the unprivileged user "startracker" (groups video, dialout, i2c);
#   4. installs /etc/startracker/config.yaml (only if absent), builds the pattern
#      database its lens needs into /var/lib/startracker, installs the udev rule, the
#      config.txt fragment and the cmdline.txt console change (backups kept);
#   5. installs and enables systemd/startracker.service.
# Arducam's libcamera (needed for the OV2311 Pivariety) is NOT installed here:
# see firmware_config/config.txt.fragment. A reboot is needed after the first run.
set -euo pipefail

PREFIX=/opt/startracker
ETC=/etc/startracker
SERVICE_USER=startracker
BOOT=/boot/firmware
SRC="$(cd "$(dirname "$0")/.." && pwd)"
MARK_BEGIN="# >>> startracker >>>"
MARK_END="# <<< startracker <<<"

if [ "$(id -u)" != 0 ]; then
    echo "install_pi.sh: run as root (sudo $0)" >&2
    exit 2
fi

echo "== apt packages"
apt-get update -qq
apt-get install -y -qq --no-install-recommends python3-venv python3-pip rsync v4l-utils \
    libraspberrypi-bin >/dev/null || \
apt-get install -y -qq --no-install-recommends python3-venv python3-pip rsync v4l-utils >/dev/null

echo "== python3-picamera2 (pinned: tracker/capture/picamera2_source.py says why)"
# picamera2 0.3.20 can time out and cancel a capture; from 0.3.26 it sets the
# ExposureTimeMode control, which Arducam's libcamera 0.3.x lacks.
if [ -z "${PICAMERA2_VERSION:-}" ]; then
    PICAMERA2_VERSION=$(apt-cache madison python3-picamera2 | awk '{print $3}' | while read -r v; do
        if dpkg --compare-versions "$v" ge 0.3.20 && dpkg --compare-versions "$v" lt 0.3.26; then
            echo "$v"; break
        fi
    done)
fi
if [ -z "$PICAMERA2_VERSION" ]; then
    echo "install_pi.sh: the archive holds no python3-picamera2 0.3.20 .. 0.3.25;" \
         "set PICAMERA2_VERSION=<version> (apt-cache madison python3-picamera2)" >&2
    exit 2
fi
apt-mark unhold python3-picamera2 >/dev/null 2>&1 || true
apt-get install -y -qq --no-install-recommends --allow-downgrades \
    "python3-picamera2=$PICAMERA2_VERSION" >/dev/null
apt-mark hold python3-picamera2 >/dev/null
echo "python3-picamera2 $PICAMERA2_VERSION installed and held"

echo "== program in $PREFIX"
mkdir -p "$PREFIX"
rsync -a --delete --exclude .venv --exclude .git --exclude build --exclude '__pycache__' \
    "$SRC/" "$PREFIX/"
if [ ! -x "$PREFIX/.venv/bin/python" ]; then
    python3 -m venv --system-site-packages "$PREFIX/.venv"
fi
"$PREFIX/.venv/bin/python" -m pip install -q --disable-pip-version-check \
    "numpy<2" "opencv-python-headless==4.11.0.86" -c "$PREFIX/constraints.txt" \
    -e "$PREFIX" pytest
"$PREFIX/.venv/bin/python" -c "import picamera2" 2>/dev/null \
    || echo "warning: the venv cannot import picamera2 (is python3-picamera2 installed?)" >&2

echo "== user $SERVICE_USER"
if ! id "$SERVICE_USER" >/dev/null 2>&1; then
    useradd --system --no-create-home --home-dir /var/lib/startracker \
        --shell /usr/sbin/nologin "$SERVICE_USER"
fi
groupadd -f i2c        # Raspberry Pi OS has it; the unit's SupplementaryGroups needs it
usermod -a -G video,dialout,i2c "$SERVICE_USER"

echo "== configuration"
install -d -m 0755 "$ETC"
if [ ! -e "$ETC/config.yaml" ]; then
    install -m 0644 "$SRC/firmware_config/config.yaml" "$ETC/config.yaml"
fi
"$PREFIX/.venv/bin/tracker" config --config "$ETC/config.yaml" >/dev/null
# The lost-in-space pattern database for the configured lens, built now (seconds to a
# minute on a Pi) into the unit's StateDirectory, so the service's first start does not.
install -d -m 0750 -o "$SERVICE_USER" -g "$SERVICE_USER" /var/lib/startracker
runuser -u "$SERVICE_USER" -- "$PREFIX/.venv/bin/tracker" database build \
    --config "$ETC/config.yaml" --cache-dir /var/lib/startracker
install -m 0644 "$SRC/firmware_config/99-startracker.rules" /etc/udev/rules.d/99-startracker.rules
udevadm control --reload || true
udevadm trigger --subsystem-match=tty || true

echo "== firmware: $BOOT/config.txt and cmdline.txt"
if [ -f "$BOOT/config.txt" ]; then
    if ! grep -qF "$MARK_BEGIN" "$BOOT/config.txt"; then
        cp "$BOOT/config.txt" "$BOOT/config.txt.bak-startracker"
        { echo; echo "[all]"; echo "$MARK_BEGIN"; cat "$SRC/firmware_config/config.txt.fragment"
          echo "$MARK_END"; } >> "$BOOT/config.txt"
    fi
    if grep -qE 'console=(serial0|ttyAMA0)' "$BOOT/cmdline.txt"; then
        cp "$BOOT/cmdline.txt" "$BOOT/cmdline.txt.bak-startracker"
        sed -i -E 's/ ?console=(serial0|ttyAMA0),[0-9]+//g' "$BOOT/cmdline.txt"
    fi
    systemctl disable --now serial-getty@ttyAMA0.service 2>/dev/null || true
else
    echo "warning: $BOOT/config.txt not found; apply firmware_config/ by hand" >&2
fi

echo "== systemd unit"
install -m 0644 "$SRC/systemd/startracker.service" /etc/systemd/system/startracker.service
systemd-analyze verify /etc/systemd/system/startracker.service
systemctl daemon-reload
systemctl enable startracker.service
if systemctl is-active --quiet startracker.service; then
    systemctl restart startracker.service
fi

echo "done. Reboot if the firmware files changed, then: $PREFIX/.venv/bin/tracker selftest"
echo "and: systemctl status startracker; journalctl -u startracker -f"
