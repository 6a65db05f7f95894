"""What the cameras see: white particles as Gaussian spots on the dim, LED-lit black top layer.

Appearance model (modelling choices, tuned to look like the paper's images, not measured):
- A particle of diameter D at distance r from a camera images as a disc of radius
  f * m(theta) * D / (2 r) capture pixels (f focal length, m the fisheye's local magnification relative to
  the axis), blurred by the lens (Gaussian PSF, `psf_sigma_capture_px`: the paper notes that focus is not very
  accurate). A uniform disc of radius a has variance a^2 / 4 per axis, so the spot is a Gaussian with
  sigma^2 = a^2 / 4 + sigma_psf^2 that keeps the disc's light energy.
- The disc's radiance is that of a white sphere under the LED light, which the stiff base layer diffuses into a
  nearly uniform illumination of the particle layer; the lens' relative illumination falls off as cos(theta).
  A far particle is dimmer only because its disc is smaller than the blur (its light energy, radiance times
  disc area, is spread over the PSF): the inverse-square law of an unresolved source.
- The background is the black protective layer seen through the clear silicone (the particle layer's top
  face), lit the same way but much darker; rays that miss the surface see the sensor's dark frame.
- Everything adds (particles are sparse: about 1 per mm^3) and the camera clips at 255.

Two resolutions share this model: "capture" (320 x 240, what a real camera delivers, which
tactile_description.imaging.crop_and_downsample turns into the model image) and "output" (the model image
drawn directly, the fast path). A spot drawn directly at output resolution is the capture spot convolved
with the area-averaging box of INTER_AREA (width w = crop / output capture pixels), whose variance adds
w^2 / 12. The fast path's background is the capture background downsampled by INTER_AREA itself. The test
suite checks that the two paths agree.

Spots are drawn with np.add.at over all cameras into one padded canvas (no Python loop over particles).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from tactile_description import SensorDescription
from tactile_sim.camera import CameraRig
from tactile_sim.particles import ParticleField

RESOLUTIONS = ("output", "capture")

#: Step of the central differences of a spot's size and brightness (as the projection's, camera.py).
_GRADIENT_STEP_M = 1e-6


@dataclass(frozen=True)
class Optics:
    """Appearance constants of the simulated sensor, in 8-bit grey levels (modelling choices, see module doc)."""

    particle_radiance: float = 250.0        # a white particle large enough to fill pixels, on the optical axis
    background_radiance: float = 30.0       # the black top layer, on the optical axis
    frame_level: float = 6.0                # the sensor's frame, seen beyond the edges of the surface
    psf_sigma_capture_px: float = 0.75      # lens blur, capture pixels
    window_sigmas: float = 3.0              # a spot is drawn out to this many sigma (its window in the canvas)
    redraw_grey_levels: float = 0.5         # a moved particle is redrawn when it could change a pixel by more
    exact_motion_fraction: float = 0.03     # motions beyond this fraction of the distance to the lens: exact


@dataclass(frozen=True)
class Spots:
    """Gaussian spots, one per (camera, particle) pair, in the pixels of one resolution."""

    camera_index: np.ndarray  # (P,) int
    uv_px: np.ndarray         # (P, 2)
    sigma_px: np.ndarray      # (P,)
    peak: np.ndarray          # (P,) grey levels at the centre


class ParticleRenderer:
    """Draws the particles of one sensor through all its cameras at one resolution, as float32 (C, H, W)."""

    def __init__(self, sensor: SensorDescription, particles: ParticleField, resolution: str = "output",
                 optics: Optics | None = None):
        if resolution not in RESOLUTIONS:
            raise ValueError(f"resolution must be one of {RESOLUTIONS}, got {resolution!r}")
        self.sensor = sensor
        self.particles = particles
        self.resolution = resolution
        self.optics = optics or Optics()
        if not self.optics.psf_sigma_capture_px > 0:
            raise ValueError(f"Optics.psf_sigma_capture_px must be > 0 (a lens always blurs; a zero-width spot has "
                             f"no Gaussian), got {self.optics.psf_sigma_capture_px}")
        self.rig = CameraRig(sensor.cameras)
        size = self.rig.output_size if resolution == "output" else self.rig.capture_size
        self.width, self.height = size
        self.n_cameras = self.rig.n_cameras
        # Capture pixels per target pixel along x and y (1 at capture resolution).
        self._box_px = 1.0 / self.rig.output_per_capture_px if resolution == "output" else np.ones(2)
        self._area_scale = 1.0 / float(np.prod(self._box_px))   # capture pixels^2 per target pixel^2
        self.max_sigma_px = float(self._sigma_px(self._nearest_disc_radius_capture_px()))
        self.window_radius = max(1, math.ceil(self.optics.window_sigmas * self.max_sigma_px))
        r = self.window_radius
        self._padded = (self.height + 2 * r, self.width + 2 * r)
        # The cameras' padded images, then a tail that catches what falls outside all of them: a visible spot's
        # window reaches r rows (and r pixels) past the last camera's padding, and one above the first camera's
        # has negative taps (numpy counts them from the end). crop_canvas ignores the tail.
        self._cameras_size = self.n_cameras * self._padded[0] * self._padded[1]
        self._canvas_size = self._cameras_size + (r + 1) * self._padded[1]
        offsets = np.arange(-r, r + 1)
        self._offsets = offsets.astype(np.float32)
        self._taps = (offsets[:, None] * self._padded[1] + offsets[None, :]).ravel()   # flat window offsets
        self._centre_limit = np.array([[self.width + r], [self.height + r]])
        self.background = self._background()
        n = len(particles)
        self.rest_spots = self.spots(np.repeat(np.arange(self.n_cameras), n), np.tile(particles.positions_m,
                                     (self.n_cameras, 1)), np.tile(np.arange(n), self.n_cameras))
        # The rest spots' windows, kept (one row per spot) so that a frame subtracts a moved particle's rest spot
        # by a gather.
        rest_taps, rest_weights = self.windows(self.rest_spots)
        self.reference = self.background + self.crop_canvas(self._scatter(rest_taps, rest_weights))
        self._rest_window_base = rest_taps[len(self._taps) // 2].copy()             # the centre tap
        self._rest_weights_negated = np.ascontiguousarray(-rest_weights.T)
        self._pair_table = self._linearisation()                                      # (C * N, 20)
        min_redraw_m2 = self._min_redraw_displacement_m() ** 2                        # (C, N)
        self._min_redraw_m2 = np.ascontiguousarray(min_redraw_m2.T, dtype=np.float32)  # (N, C)
        self._min_redraw_any_m2 = min_redraw_m2.min(axis=0).astype(np.float32)        # (N,)

    # --- appearance ---------------------------------------------------------------------------------------
    def _nearest_disc_radius_capture_px(self) -> float:
        """The largest particle disc at rest: the biggest sphere at the particle layer's bottom face on an axis."""
        _, bottom = self.sensor.layer_depth_range_m(self.sensor.particles.layer)
        nearest_m = float(np.min(-bottom - self.rig.centres_m[:, 2]))
        return float(self.rig.focal_px.max()) * 0.5 * self.sensor.particles.diameter_max_m / nearest_m

    def _sigma_px(self, disc_radius_capture_px):
        """Spot sigma in target pixels: disc variance a^2/4 + PSF^2 (+ w^2/12 of the area downsampling)."""
        variance = 0.25 * disc_radius_capture_px ** 2 + self.optics.psf_sigma_capture_px ** 2
        box = float(self._box_px.mean())
        return np.sqrt(variance + box * box / 12.0 * (box > 1.0)) / box

    def _disc_and_radiance(self, camera_index, points_m: np.ndarray, particle_index: np.ndarray):
        """Projection of particles at `points_m`, their disc radius (capture px) times their distance (m), and
        their radiance (grey levels)."""
        proj = self.rig.project(camera_index, points_m)
        radius_times_distance = (self.rig.focal_px[camera_index] * proj.magnification * 0.5
                                 * self.particles.diameters_m[particle_index])
        radiance = (self.optics.particle_radiance * self.particles.reflectance[particle_index]
                    * np.maximum(np.cos(proj.theta_rad), 0.0))
        return proj, radius_times_distance, radiance

    def _sigma_and_peak(self, radius_times_distance, distance_m, radiance):
        """Spot sigma (target px) and peak grey level of a particle's disc at `distance_m` from the lens."""
        # A sphere cannot come closer to the lens than about its own size (this also keeps 1 / 0 out).
        disc_radius = radius_times_distance / np.maximum(distance_m, self.sensor.particles.diameter_min_m)
        sigma = np.minimum(self._sigma_px(disc_radius), self.max_sigma_px)
        # Light energy of the disc (radiance * pi a^2, in target pixels^2) spread over a Gaussian 2 pi sigma^2.
        peak = radiance * disc_radius ** 2 * self._area_scale / (2.0 * sigma ** 2)
        return sigma, peak

    def spots(self, camera_index: np.ndarray, points_m: np.ndarray, particle_index: np.ndarray) -> Spots:
        """Spots of particles (by index into the field, for diameter and reflectance) at `points_m`: exact."""
        proj, radius_times_distance, radiance = self._disc_and_radiance(camera_index, points_m, particle_index)
        sigma, peak = self._sigma_and_peak(radius_times_distance, proj.distance_m, radiance)
        uv = self._capture_to_target_px(camera_index, proj.uv_capture_px)
        return Spots(camera_index=np.asarray(camera_index), uv_px=uv, sigma_px=sigma, peak=peak)

    def _capture_to_target_px(self, camera_index, uv_capture: np.ndarray) -> np.ndarray:
        if self.resolution == "capture":
            return uv_capture
        return self.rig.capture_to_output_px(camera_index, uv_capture)

    def _project(self, camera_index, points_m: np.ndarray) -> np.ndarray:
        """(P, 2) spot centres of particles at `points_m`, in this renderer's pixels."""
        return self._capture_to_target_px(camera_index, self.rig.project_capture_px(camera_index, points_m))

    def _linearisation(self) -> np.ndarray:
        """(C * N, 20) float32 per rest (camera, particle) pair, what `moved_spots` needs to move a spot to first
        order: the projection's Jacobian (columns 0-5, target pixels per metre, row-major 2 x 3), the unit ray
        from the lens (6-8, the gradient of the distance), the rest spot centre (9-10), distance (11), disc radius
        times distance (12) and radiance (13), and the gradients of the last two (14-16, 17-19; per metre)."""
        n = len(self.particles)
        cams = self.rest_spots.camera_index
        points = np.tile(self.particles.positions_m, (self.n_cameras, 1))
        particle = np.tile(np.arange(n), self.n_cameras)
        jacobian = self.rig.jacobian_output_px_per_m(cams, points)
        if self.resolution == "capture":
            jacobian = jacobian / self.rig.output_per_capture_px[:, None]
        proj, radius_times_distance, radiance = self._disc_and_radiance(cams, points, particle)
        ray = (points - self.rig.centres_m[cams]) / proj.distance_m[:, None]
        gradients = np.empty((len(points), 6))
        for axis in range(3):  # central differences, as for the projection's Jacobian
            step = np.zeros(3)
            step[axis] = _GRADIENT_STEP_M
            _, k_plus, l_plus = self._disc_and_radiance(cams, points + step, particle)
            _, k_minus, l_minus = self._disc_and_radiance(cams, points - step, particle)
            gradients[:, axis] = (k_plus - k_minus) / (2 * _GRADIENT_STEP_M)
            gradients[:, 3 + axis] = (l_plus - l_minus) / (2 * _GRADIENT_STEP_M)
        return np.column_stack([jacobian.reshape(-1, 6), ray, self.rest_spots.uv_px, proj.distance_m,
                                radius_times_distance, radiance, gradients]).astype(np.float32)

    def moved_spots(self, rest_index: np.ndarray, displacements_m: np.ndarray) -> Spots:
        """Spots of rest pairs `rest_index` (camera * N + particle) moved by `displacements_m` (P, 3).

        To first order: centre + J d, and distance, disc size and radiance each plus its gradient . d (size and
        brightness then follow as in `spots`). The neglected second order is about |d| / distance of each change,
        so the few spots (~2 % in a deep press) that move by more than `exact_motion_fraction` of their distance
        are placed by the exact projection. For the deepest press (1.5 mm) right above a camera, spots shift by
        up to 3.5 output pixels and the error stays under 0.05 px, peaks within 5 % (tested).
        """
        t = self._pair_table[rest_index].T                                          # (20, P)
        d = np.ascontiguousarray(np.asarray(displacements_m, dtype=np.float32).T)   # (3, P)
        u = t[9] + t[0] * d[0] + t[1] * d[1] + t[2] * d[2]
        v = t[10] + t[3] * d[0] + t[4] * d[1] + t[5] * d[2]
        distance = t[11] + t[6] * d[0] + t[7] * d[1] + t[8] * d[2]
        radius_times_distance = t[12] + t[14] * d[0] + t[15] * d[1] + t[16] * d[2]
        radiance = t[13] + t[17] * d[0] + t[18] * d[1] + t[19] * d[2]
        sigma, peak = self._sigma_and_peak(radius_times_distance, distance, radiance)
        uv = np.stack([u, v], axis=1)
        # Pairs that move by a sizeable fraction of their distance to the lens are projected exactly.
        moved2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
        far = np.flatnonzero(moved2 > np.square(self.optics.exact_motion_fraction * t[11]))
        if far.size:
            particle = rest_index[far] % len(self.particles)
            uv[far] = self._project(rest_index[far] // len(self.particles),
                                    self.particles.positions_m[particle] + d[:, far].T)
        return Spots(camera_index=rest_index // len(self.particles), uv_px=uv, sigma_px=sigma, peak=peak)

    def _background(self) -> np.ndarray:
        """(C, H, W) float32 background: the lit black top layer inside the surface, the dark frame outside."""
        o = self.optics
        cap_w, cap_h = self.rig.capture_size
        v, u = np.mgrid[0:cap_h, 0:cap_w]
        uv = np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64)
        top, _ = self.sensor.layer_depth_range_m(self.sensor.particles.layer)
        grid = self.sensor.grid
        images = []
        for cam in range(self.n_cameras):
            rays = self.rig.ray_directions(cam, uv)
            centre = self.rig.centres_m[cam]
            upward = rays[:, 2] > 1e-6
            travel = np.where(upward, (-top - centre[2]) / np.where(upward, rays[:, 2], 1.0), 0.0)
            hit = centre[:2] + rays[:, :2] * travel[:, None]
            inside = (upward & (hit[:, 0] >= 0) & (hit[:, 0] <= grid.width_m)
                      & (hit[:, 1] >= 0) & (hit[:, 1] <= grid.length_m))
            level = np.where(inside, o.background_radiance * np.clip(rays[:, 2], 0.0, 1.0), o.frame_level)
            level = level.reshape(cap_h, cap_w).astype(np.float32)
            if self.resolution == "output":
                c = self.rig.crop
                level = cv2.resize(level[c.y:c.y + c.height, c.x:c.x + c.width], self.rig.output_size,
                                   interpolation=cv2.INTER_AREA)
            images.append(level)
        return np.stack(images)

    def _min_redraw_displacement_m(self) -> np.ndarray:
        """(C, N) smallest displacement of each particle that can change a pixel of a camera by
        `redraw_grey_levels`: the steepest slope of a Gaussian spot is peak / (sigma sqrt(e)) per pixel, and a
        displacement d moves the spot by at most |J|_F |d| pixels (J the projection's Jacobian)."""
        px_per_m = np.sqrt(np.square(self._pair_table[:, 0:6].astype(np.float64)).sum(axis=1))
        grey_per_px = self.rest_spots.peak / (self.rest_spots.sigma_px * math.sqrt(math.e))
        sensitivity = np.maximum(px_per_m * grey_per_px, 1e-12)
        return (self.optics.redraw_grey_levels / sensitivity).reshape(self.n_cameras, len(self.particles))

    def render_displaced(self, displacements_m: np.ndarray) -> np.ndarray:
        """(C, H, W) float32 image with the particles moved by `displacements_m` (N, 3): the fast path.

        Starts from the reference (rest) image and redraws only the (camera, particle) pairs whose displacement
        can change a pixel by `redraw_grey_levels` (see _min_redraw_displacement_m): the rest spot is
        subtracted and the spot at the new position (moved_spots), with its new size and brightness, added.
        """
        disp = np.asarray(displacements_m, dtype=np.float32)
        moved2 = np.square(disp) @ np.ones(3, dtype=np.float32)
        candidates = np.flatnonzero(moved2 > self._min_redraw_any_m2)
        if candidates.size == 0:
            return self.reference.copy()
        redraw = moved2[candidates, None] > self._min_redraw_m2[candidates]         # (M, C)
        which, cams = np.nonzero(redraw)
        particle = candidates[which]
        rest = cams * len(self.particles) + particle
        new_taps, new_weights = self.windows(self.moved_spots(rest, disp[particle]))
        canvas = np.zeros(self._canvas_size, dtype=np.float32)
        np.add.at(canvas, (self._rest_window_base[rest, None] + self._taps).ravel(),
                  self._rest_weights_negated[rest].ravel())
        np.add.at(canvas, new_taps.ravel(), new_weights.ravel())
        return self.reference + self.crop_canvas(canvas)

    # --- drawing ------------------------------------------------------------------------------------------
    def windows(self, spots: Spots) -> tuple[np.ndarray, np.ndarray]:
        """Each spot's window in the flat padded canvas: (K, P) tap indices and (K, P) float32 weights, K = (2r+1)^2.

        The Gaussian is separable, so a window is the outer product of two 1-D profiles. A spot whose centre
        pixel lies more than the window radius outside the image gets zero weights (it cannot reach a visible
        pixel by more than exp(-window_sigmas^2 / 2) of its peak). Taps of a visible spot that fall outside its
        camera's padded image land in another camera's padding or in the canvas' tail, never in a visible pixel
        (see __init__). The spot index runs along the last axis:
        numpy broadcasts over a long inner axis many times faster than over a 5-long one.
        """
        r = self.window_radius
        hp, wp = self._padded
        uv = np.ascontiguousarray(np.asarray(spots.uv_px, dtype=np.float32).T)     # (2, P): u, v
        centre = np.rint(uv)
        pixel = centre.astype(np.int64)
        inside = (pixel >= -r) & (pixel < self._centre_limit)
        visible = inside[0] & inside[1]
        sigma = np.asarray(spots.sigma_px, dtype=np.float32)
        offset = self._offsets[:, None, None] + (centre - uv)                       # (2r + 1, 2, P)
        profile = np.exp(np.square(offset) * (np.float32(-0.5) / np.square(sigma)))
        rows = profile[:, 1, :] * np.where(visible, spots.peak, 0.0).astype(np.float32)
        weights = rows[:, None, :] * profile[None, :, 0, :]                          # (2r + 1, 2r + 1, P)
        base = np.where(visible, spots.camera_index * (hp * wp) + pixel[1] * wp + pixel[0], 0) + (r * wp + r)
        return self._taps[:, None] + base, weights.reshape(len(self._taps), len(base))

    def _scatter(self, taps: np.ndarray, weights: np.ndarray) -> np.ndarray:
        """Flat float32 padded canvas (C * Hp * Wp) with each weight added at its tap (arrays of equal shape)."""
        canvas = np.zeros(self._canvas_size, dtype=np.float32)
        np.add.at(canvas, taps.ravel(), weights.ravel())
        return canvas

    def draw(self, spots: Spots) -> np.ndarray:
        """(C, H, W) float32 image of the spots alone (no background)."""
        return self.crop_canvas(self._scatter(*self.windows(spots)))

    def crop_canvas(self, canvas: np.ndarray) -> np.ndarray:
        """The visible (C, H, W) part of a flat padded canvas (a view)."""
        r = self.window_radius
        hp, wp = self._padded
        return canvas[:self._cameras_size].reshape(self.n_cameras, hp, wp)[:, r:r + self.height, r:r + self.width]

    def render(self, positions_m: np.ndarray) -> np.ndarray:
        """(C, H, W) float32 image with every particle drawn afresh at `positions_m` (N, 3): the slow, exact path."""
        n = len(self.particles)
        cams = np.repeat(np.arange(self.n_cameras), n)
        spots = self.spots(cams, np.tile(positions_m, (self.n_cameras, 1)), np.tile(np.arange(n), self.n_cameras))
        return self.background + self.draw(spots)
