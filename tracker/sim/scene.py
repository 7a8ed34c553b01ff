"""Light that is not stars: the Sun's glare, lens ghosts, the lunar horizon, the Earth, particles.

A :class:`Scene` is what tracker.sim.sky.render_sky adds to a star field
under the realistic sensor model: extra light (e-/pixel) under the stars,
the pixels where the sky is hidden (stars behind the terrain or the
Earth's disc are not seen), extra charge deposited by particles, and a
label image saying what put light where (for scoring false detections).

Generators, each deterministic for a given ``np.random.Generator``:

* :func:`sun_glare`: stray light of the Sun just outside the frame, a
  profile A (1 + (r / r0)^2)^(-p/2) whose nearest frame pixel gets several
  times the full well, so a band along one edge saturates and the light
  falls steeply across the frame;
* :func:`lens_ghosts`: out-of-focus images of the aperture on the line
  from the Sun through the image centre (discs and rings with soft edges,
  faint; stars show through them);
* :func:`particle_tracks`: a solar-particle event: tracks of particles at
  isotropic incidence through a sensitive layer ``thickness_px`` thick,
  projected length thickness * tan(theta), charge spread by diffusion over
  neighbouring pixels (tracks two or three pixels wide);
* :func:`lunar_scene`: all of the above plus a sunlit, cratered horizon
  across the lower part of the field and, often, the Earth as a disc or
  crescent (its night side dark but still hiding the stars behind it).

Labels: :data:`LABELS` maps each kind to its value in ``Scene.labels``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["Scene", "LABELS", "sun_glare", "lens_ghosts", "particle_tracks", "lunar_scene",
           "glare_scene", "EARTH_RADIUS_RAD"]

LABELS = {"sky": 0, "terrain": 1, "earth": 2, "glare": 3, "ghost": 4, "track": 5}
EARTH_RADIUS_RAD = math.radians(1.9) / 2.0   # the Earth's disc seen from the Moon
_GLARE_LABEL_E = 200.0      # glare brighter than this (e-) counts as the glare's area
_GHOST_LABEL_FRACTION = 0.2  # a ghost's area: where it gives this fraction of its level


@dataclass
class Scene:
    """Light, occlusion and particle charge of one frame (arrays of the frame's shape)."""

    light_e: np.ndarray                 # float64 e-/pixel added to the sky
    occluded: np.ndarray                # bool: the sky is hidden here
    deposits: np.ndarray                # float64 e- of particle tracks
    deposit_truth: list = field(default_factory=list)
    labels: np.ndarray | None = None    # uint8 LABELS of what dominates each pixel
    bodies: list = field(default_factory=list)  # one dict per object, for the truth file

    @classmethod
    def empty(cls, shape: tuple[int, int]) -> Scene:
        return cls(np.zeros(shape), np.zeros(shape, bool), np.zeros(shape),
                   labels=np.zeros(shape, np.uint8))

    def add_light(self, light: np.ndarray, label: str, where: np.ndarray | None = None) -> None:
        """Add ``light`` (e-); label the pixels ``where`` (default: none)."""
        self.light_e += light
        if where is not None:
            self.labels[where] = LABELS[label]


def _grid(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    rows, cols = shape
    return np.arange(cols, dtype=np.float64)[None, :], np.arange(rows, dtype=np.float64)[:, None]


def _outside_point(shape: tuple[int, int], rng: np.random.Generator,
                   reach_px: tuple[float, float],
                   edge: int | None = None) -> tuple[float, float, float]:
    """A point (x, y) beyond an edge (0 top, 1 bottom, 2 left, 3 right; None: random) by a
    distance drawn from ``reach_px``, and that distance."""
    rows, cols = shape
    d = float(rng.uniform(*reach_px))
    edge = int(rng.integers(4)) if edge is None else edge
    along = float(rng.uniform(0.1, 0.9))
    x, y = [(along * (cols - 1), -d), (along * (cols - 1), rows - 1 + d),
            (-d, along * (rows - 1)), (cols - 1 + d, along * (rows - 1))][edge]
    return x, y, d


def sun_glare(scene: Scene, rng: np.random.Generator, full_well_e: float, *,
              edge: int | None = None) -> tuple[float, float]:
    """Add the Sun's stray light from just outside the frame; returns its centre (x, y).

    ``edge`` (0 top, 1 bottom, 2 left, 3 right) fixes the side; else random.
    """
    shape = scene.light_e.shape
    x0, y0, d = _outside_point(shape, rng, (20.0, 300.0), edge)
    r0 = float(rng.uniform(10.0, 40.0))
    power = float(rng.uniform(3.0, 4.0))
    at_edge = float(rng.uniform(1.5, 10.0)) * full_well_e   # at the nearest frame pixel
    amplitude = at_edge * (1.0 + (d / r0) ** 2) ** (power / 2.0)
    gx, gy = _grid(shape)
    r2 = (gx - x0) ** 2 + (gy - y0) ** 2
    light = amplitude * (1.0 + r2 / r0 ** 2) ** (-power / 2.0)
    scene.add_light(light, "glare", light > _GLARE_LABEL_E)
    scene.bodies.append({"kind": "glare", "x": x0, "y": y0, "r0_px": r0, "power": power,
                         "edge_e": at_edge})
    return x0, y0


def lens_ghosts(scene: Scene, rng: np.random.Generator, source: tuple[float, float],
                count: int) -> None:
    """Add ``count`` ghosts of a bright ``source`` (x, y) on its line through the centre."""
    rows, cols = scene.light_e.shape
    cx, cy = (cols - 1) / 2.0, (rows - 1) / 2.0
    gx, gy = _grid((rows, cols))
    for _ in range(count):
        k = float(rng.uniform(-1.3, 0.3))
        x, y = cx + k * (source[0] - cx), cy + k * (source[1] - cy)
        radius = float(rng.uniform(12.0, 90.0))
        soft = float(rng.uniform(0.7, 4.0))
        level = float(rng.uniform(15.0, 600.0))
        ring = bool(rng.random() < 0.35)
        r = np.sqrt((gx - x) ** 2 + (gy - y) ** 2)
        # smooth step down at the rim; a ring also steps up at 60-85 % of its radius
        disc = 0.5 * (1.0 - np.tanh((r - radius) / soft))
        if ring:
            inner = radius * float(rng.uniform(0.6, 0.85))
            disc *= 0.5 * (1.0 + np.tanh((r - inner) / soft))
        light = level * disc
        scene.add_light(light, "ghost", (light > _GHOST_LABEL_FRACTION * level)
                        & (scene.labels == LABELS["sky"]))
        scene.bodies.append({"kind": "ghost", "x": x, "y": y, "radius_px": radius,
                             "level_e": level, "ring": ring})


def particle_tracks(scene: Scene, rng: np.random.Generator, count: int, *,
                    thickness_px: float = 1.5, mean_e: float = 900.0,
                    max_length_px: float = 60.0, diffusion_px: float = 0.45) -> None:
    """Add ``count`` particle tracks to ``scene.deposits`` and their truth.

    Incidence is isotropic over the half-sphere (cos theta uniform), so the
    projected length thickness * tan(theta) is mostly a few pixels with a
    long tail (capped at ``max_length_px``). A track's charge is ``mean_e``
    (e- per pixel of path) times a lognormal straggling factor times its
    path in the silicon, sqrt(length^2 + thickness^2) px, spread evenly
    along the projected length; each deposit is spread by a Gaussian of
    ``diffusion_px``.
    """
    rows, cols = scene.deposits.shape
    flat = scene.deposits.ravel()
    for _ in range(count):
        cos_t = max(float(rng.uniform(0.0, 1.0)), 1e-3)
        length = min(thickness_px * math.sqrt(1.0 - cos_t ** 2) / cos_t, max_length_px)
        angle = float(rng.uniform(0.0, 2.0 * math.pi))
        x0, y0 = float(rng.uniform(0, cols - 1)), float(rng.uniform(0, rows - 1))
        straggle = float(rng.lognormal(0.0, 0.4))
        steps = max(2, int(math.ceil(length / 0.2)) + 1)
        t = np.linspace(0.0, 1.0, steps)
        xs = x0 + t * length * math.cos(angle)
        ys = y0 + t * length * math.sin(angle)
        charge = mean_e * straggle * math.hypot(length, thickness_px)
        # Gaussian splat of each sample over its 5 x 5 neighbourhood
        ix, iy = np.rint(xs).astype(np.int64), np.rint(ys).astype(np.int64)
        off = np.arange(-2, 3)
        wx = np.exp(-0.5 * ((ix[:, None] + off[None, :] - xs[:, None]) / diffusion_px) ** 2)
        wy = np.exp(-0.5 * ((iy[:, None] + off[None, :] - ys[:, None]) / diffusion_px) ** 2)
        w = wy[:, :, None] * wx[:, None, :]
        w *= charge / steps / w.sum(axis=(1, 2), keepdims=True)
        cc = ix[:, None, None] + off[None, None, :]
        rr = iy[:, None, None] + off[None, :, None]
        inside = (cc >= 0) & (cc < cols) & (rr >= 0) & (rr < rows)
        rr, cc = np.broadcast_arrays(rr, cc)
        np.add.at(flat, (rr * cols + cc)[inside], w[inside])
        scene.deposit_truth.append({"kind": "cosmic_ray", "x": float(xs.mean()),
                                    "y": float(ys.mean()), "length_px": float(length),
                                    "charge_e": float(charge)})
    scene.labels[scene.deposits > 0.2 * mean_e] = LABELS["track"]


def _smooth_field(shape: tuple[int, int], rng: np.random.Generator, scale_px: float,
                  contrast: float) -> np.ndarray:
    """1 + contrast * a smooth random field of unit spread and correlation ``scale_px``."""
    rows, cols = shape
    ky = np.fft.fftfreq(rows)[:, None]
    kx = np.fft.rfftfreq(cols)[None, :]
    spectrum = np.exp(-2.0 * (math.pi * scale_px) ** 2 * (kx ** 2 + ky ** 2))
    noise = rng.normal(size=(rows, cols // 2 + 1)) + 1j * rng.normal(size=(rows, cols // 2 + 1))
    field_ = np.fft.irfft2(noise * spectrum, s=(rows, cols))
    field_ /= max(float(field_.std()), 1e-12)
    return np.clip(1.0 + contrast * field_, 0.1, None)


def _terrain(scene: Scene, rng: np.random.Generator, full_well_e: float,
             sun: tuple[float, float]) -> dict:
    """A sunlit cratered surface below a rough horizon; returns its truth."""
    rows, cols = scene.light_e.shape
    gx, gy = _grid((rows, cols))
    base = float(rng.uniform(0.55, 0.85)) * rows
    tilt = float(rng.uniform(-0.15, 0.15))
    horizon = base + tilt * (gx[0] - cols / 2.0)
    for k in range(1, 40):
        amp = float(rng.uniform(0.0, 40.0)) * k ** -1.3
        horizon += amp * np.sin(2.0 * math.pi * k * gx[0] / cols + float(rng.uniform(0, 6.3)))
    below = gy >= horizon[None, :]
    level = float(rng.uniform(0.05, 4.0)) * full_well_e
    shade = _smooth_field((rows, cols), rng, float(rng.uniform(8.0, 30.0)), 0.25)
    sun_dir = np.array(sun) - np.array([cols / 2.0, rows / 2.0])
    sun_dir /= max(float(np.hypot(*sun_dir)), 1e-9)
    craters = int(rng.integers(10, 40))
    for _ in range(craters):
        x = float(rng.uniform(0, cols - 1))
        top = float(horizon[int(np.clip(round(x), 0, cols - 1))])
        y = float(rng.uniform(top, rows + 40))
        depth = (y - top) / max(rows - top, 1.0)            # nearer craters are larger
        a = float(rng.uniform(4.0, 25.0)) * (1.0 + 3.0 * depth)
        b = a * (0.15 + 0.5 * depth)                         # foreshortened
        u, v = (gx - x) / a, (gy - y) / b
        r = np.sqrt(u * u + v * v)
        toward = (u * sun_dir[0] + v * sun_dir[1]) / np.maximum(r, 1e-9)
        inside = r < 1.0
        rim = np.exp(-0.5 * ((r - 1.0) / 0.12) ** 2)
        shade *= np.where(inside, np.where(toward > 0, 0.25, 1.2), 1.0)
        shade *= 1.0 + 0.9 * rim * np.clip(-toward, 0.0, 1.0)
    light = np.where(below, level * shade, 0.0)
    scene.add_light(light, "terrain", below)
    scene.occluded |= below
    return {"kind": "terrain", "horizon_mean_y": float(horizon.mean()), "level_e": level,
            "craters": craters}


def _earth(scene: Scene, rng: np.random.Generator, full_well_e: float, f_px: float,
           sun: tuple[float, float]) -> dict:
    """The Earth's disc, lit as a crescent to full, somewhere in the sky; returns its truth."""
    rows, cols = scene.light_e.shape
    gx, gy = _grid((rows, cols))
    radius = f_px * math.tan(EARTH_RADIUS_RAD)
    for _ in range(50):   # a centre over open sky (or just off the frame's edge)
        x = float(rng.uniform(-0.3 * radius, cols - 1 + 0.3 * radius))
        y = float(rng.uniform(-0.3 * radius, rows * 0.6))
        iy, ix = int(np.clip(round(y), 0, rows - 1)), int(np.clip(round(x), 0, cols - 1))
        if not scene.occluded[iy, ix]:
            break
    dx, dy = gx - x, gy - y
    disc = dx * dx + dy * dy <= radius * radius
    to_sun = np.array(sun) - np.array([x, y])
    to_sun /= max(float(np.hypot(*to_sun)), 1e-9)
    along = (dx * to_sun[0] + dy * to_sun[1]) / radius
    across = (-dx * to_sun[1] + dy * to_sun[0]) / radius
    phase = float(rng.uniform(-0.95, 0.9))   # terminator: -1 full, +1 new
    half_chord = np.sqrt(np.clip(1.0 - across * across, 0.0, 1.0))
    lit = disc & (along >= phase * half_chord)
    level = float(rng.uniform(0.3, 15.0)) * full_well_e
    clouds = _smooth_field((rows, cols), rng, float(rng.uniform(3.0, 12.0)), 0.35)
    light = np.where(lit, level * clouds, 0.0)
    scene.add_light(light, "earth", disc)
    scene.occluded |= disc
    return {"kind": "earth", "x": x, "y": y, "radius_px": radius, "phase": phase,
            "level_e": level}


def glare_scene(shape: tuple[int, int], rng: np.random.Generator, full_well_e: float,
                tracks: tuple[int, int] = (50, 150)) -> Scene:
    """Saturating glare from a Sun just outside the frame plus a particle event."""
    scene = Scene.empty(shape)
    sun_glare(scene, rng, full_well_e)
    particle_tracks(scene, rng, int(rng.integers(tracks[0], tracks[1] + 1)))
    return scene


def lunar_scene(shape: tuple[int, int], rng: np.random.Generator, full_well_e: float,
                f_px: float, earth_probability: float = 0.7) -> Scene:
    """A frame on the lunar surface: horizon, often the Earth, the Sun's glare, ghosts, particles.

    The Sun stands beyond the top or a side of the frame (it lights the
    terrain from there); ``f_px`` (focal length in pixels) sets the Earth's size.
    """
    scene = Scene.empty(shape)
    sun = sun_glare(scene, rng, full_well_e, edge=int(rng.choice([0, 2, 3])))
    scene.bodies.append(_terrain(scene, rng, full_well_e, sun))
    if rng.random() < earth_probability:
        scene.bodies.append(_earth(scene, rng, full_well_e, f_px, sun))
    lens_ghosts(scene, rng, sun, int(rng.integers(0, 4)))
    particle_tracks(scene, rng, int(rng.integers(50, 151)))
    return scene
