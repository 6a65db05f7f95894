"""The "numerical" ground-truth model: any indenter shape, several at once, solved on a fine surface grid.

The surface is cut into pixels (`pixels_per_bin` per bin side, aligned with the bins). The normal displacement
of the surface under a pixel-wise constant pressure is a convolution with the influence coefficients of the
compliant layer of elastic.compliant_layer, bonded to a rigid base:

- half-space part: Love's closed form for a uniform pressure on a rectangle (Johnson, Contact Mechanics, 1985,
  eq. 3.25);
- thin-layer part: the exact surface compliance of an elastic layer of thickness h bonded to a rigid base with a
  frictionless top, in Fourier space u(q) = 2 p(q) C(qh) / (E* q) with
  C(x) = ((3 - 4 nu) sinh 2x - 2x) / ((3 - 4 nu) cosh 2x + 2x^2 + 5 - 12 nu + 8 nu^2)
  (e.g. Persson, J. Phys.: Condens. Matter 24 (2012) 095008; it tends to 1 for a half-space, and for a thin layer
  to the oedometric compliance h (1 + nu)(1 - 2 nu) / (E (1 - nu))). The difference to the half-space is smooth
  and is Hankel-transformed numerically once per layer.

The contact is displacement controlled: every indenter is pressed to its own depth; their union (the lowest
indenter surface at each point) must not penetrate the gel. The non-negative pressure is found with the
constrained conjugate gradient method of Polonsky and Keer (Wear 231 (1999) 206), with the convolution done by
FFT on a zero-padded window around the contacts (so it is a linear, not a periodic, convolution). Overlapping
indenters therefore interact correctly here (unlike the analytic model, which superposes them).

Shear follows the Jaeger-Ciavarella form of Cattaneo-Mindlin (contact.stick_depth_m): q = mu (p(d) - p(d')),
with p(d') solved again at every indenter's stick depth, along the shear of the indenter that touches there.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Sequence

import numpy as np
from scipy.ndimage import map_coordinates
from scipy.special import j0

from tactile_description import SensorDescription
from tactile_description.value_checks import is_whole_number

from .contact import Contact, FlatPunch, HeightMap, Sphere, check_contact, stick_depth_m
from .elastic import CompliantLayer, compliant_layer

#: Beyond this many layer thicknesses the bonded layer's surface response is below ~1e-4 of its peak (it decays
#: like exp(-0.74 r / h)); the influence coefficients are set to zero there.
FAR_FIELD_LAYERS = 12.0


def layer_compliance_factor(qh: np.ndarray, nu: float) -> np.ndarray:
    """C(qh) of the module docstring, written with exp(-2x) so that it never overflows; C(0) = 0, C(inf) = 1."""
    x = np.asarray(qh, dtype=np.float64)
    k = 3.0 - 4.0 * nu
    e2 = np.exp(-2.0 * x)
    e4 = e2 * e2
    numerator = k * (1.0 - e4) - 4.0 * x * e2
    denominator = k * (1.0 + e4) + 2.0 * (2.0 * x * x + 5.0 - 12.0 * nu + 8.0 * nu * nu) * e2
    return numerator / denominator


@functools.lru_cache(maxsize=16)
def _layer_correction(thickness_m: float, plane_strain_modulus_pa: float, nu: float, r_max_m: float):
    """(r, dK(r)): thin-layer minus half-space surface displacement per unit point force, for r in [0, r_max].

    dK(r) = 1 / (pi E*) int_0^inf (C(qh) - 1) J0(q r) dq. The integrand tends to -1 at q = 0 (the half-space's
    1/r far field, which the layer cancels), so the integral is split with int_0^inf exp(-q h) J0(q r) dq =
    1 / sqrt(h^2 + r^2) into that closed form and a smooth, fast-decaying remainder integrated by the trapezoid
    rule (q up to 40 / h, at least 5 points per J0 period at r_max).
    """
    h = thickness_m
    r = np.linspace(0.0, r_max_m, max(64, int(math.ceil(r_max_m / (h / 64.0)))))
    q_max = 40.0 / h
    dq = min(q_max / 800.0, 2.0 * math.pi / (5.0 * max(r_max_m, h)))
    q = np.linspace(0.0, q_max, int(math.ceil(q_max / dq)) + 1)
    remainder = layer_compliance_factor(q * h, nu) - 1.0 + np.exp(-q * h)
    weights = np.full(q.size, q[1] - q[0])
    weights[[0, -1]] *= 0.5
    integral = np.empty_like(r)
    for start in range(0, r.size, 256):  # chunks keep the (r, q) table small
        block = r[start:start + 256]
        integral[start:start + 256] = j0(np.outer(block, q)) @ (remainder * weights)
    return r, (integral - 1.0 / np.sqrt(h * h + r * r)) / (math.pi * plane_strain_modulus_pa)


def _love_rectangle(x: np.ndarray, y: np.ndarray, a: float, b: float) -> np.ndarray:
    """Integral of 1 / |s - (x, y)| over the rectangle |s_x| <= a, |s_y| <= b (Love 1929; Johnson eq. 3.25).

    pi E* times the surface displacement per unit pressure. Written with asinh, whose ln|.| parts cancel
    exactly; valid where x +- a and y +- b are non-zero, which holds at every pixel centre of the grid.
    """
    xp, xm, yp, ym = x + a, x - a, y + b, y - b
    return (xp * (np.arcsinh(yp / np.abs(xp)) - np.arcsinh(ym / np.abs(xp)))
            + yp * (np.arcsinh(xp / np.abs(yp)) - np.arcsinh(xm / np.abs(yp)))
            + xm * (np.arcsinh(ym / np.abs(xm)) - np.arcsinh(yp / np.abs(xm)))
            + ym * (np.arcsinh(xm / np.abs(ym)) - np.arcsinh(xp / np.abs(ym))))


def surface_influence(layer: CompliantLayer, pixel_x_m: float, pixel_y_m: float, rows: int, cols: int) -> np.ndarray:
    """(2 rows, 2 cols) influence coefficients in wrap-around order: displacement per pascal on one pixel.

    Entry [i, j] is the displacement at a pixel offset (i, j) (negative offsets wrapped to the end) from a pixel
    under unit pressure, for a window of rows x cols pixels; zero-padding to twice the window makes the FFT
    convolution linear.
    """
    oy = np.fft.fftfreq(2 * rows, 1.0 / (2 * rows)) * pixel_y_m
    ox = np.fft.fftfreq(2 * cols, 1.0 / (2 * cols)) * pixel_x_m
    x, y = np.meshgrid(ox, oy)
    e_star = layer.plane_strain_modulus_pa
    half_space = _love_rectangle(x, y, 0.5 * pixel_x_m, 0.5 * pixel_y_m) / (math.pi * e_star)
    r = np.hypot(x, y)
    far = FAR_FIELD_LAYERS * layer.thickness_m
    table_r, table_dk = _layer_correction(layer.thickness_m, e_star, layer.poisson_ratio,
                                          float(min(r.max(), far)) + pixel_x_m + pixel_y_m)
    kernel = half_space + pixel_x_m * pixel_y_m * np.interp(r, table_r, table_dk)
    kernel[r > far] = 0.0
    return kernel


class NumericalContactModel:
    """Frictionless normal contact of any rigid indenters on the layer, plus Cattaneo-Mindlin shear traction."""

    name = "numerical"
    adds_contacts = False  # every indenter in one solve

    def __init__(self, sensor: SensorDescription, pixels_per_bin: int = 8, tolerance: float = 1e-10,
                 max_iterations: int = 2000):
        if not is_whole_number(pixels_per_bin):
            raise ValueError(f"pixels_per_bin must be a whole number >= 1, got {pixels_per_bin!r}")
        self.sensor = sensor
        self.layer = compliant_layer(sensor)
        self.pixels_per_bin = pixels_per_bin
        self.tolerance = tolerance
        self.max_iterations = max_iterations
        grid = sensor.grid
        self.pixel_x_m = grid.bin_width_m / pixels_per_bin
        self.pixel_y_m = grid.bin_length_m / pixels_per_bin
        self._kernels: dict[tuple[int, int], np.ndarray] = {}

    # --- geometry -----------------------------------------------------------------------------------------------

    def _window(self, contacts: Sequence[Contact]) -> tuple[slice, slice] | None:
        """Pixel window (whole bins, on the surface) around every place an indenter comes within 2 depths."""
        grid, s = self.sensor.grid, self.pixels_per_bin
        boxes = []
        for c in contacts:
            reach = _footprint_radius_m(c.shape, 2.0 * c.depth_m)
            boxes.append((c.x_m - reach, c.x_m + reach, c.y_m - reach, c.y_m + reach))
        x0, x1 = min(b[0] for b in boxes), max(b[1] for b in boxes)
        y0, y1 = min(b[2] for b in boxes), max(b[3] for b in boxes)
        c0 = max(0, math.floor(x0 / grid.bin_width_m))
        c1 = min(grid.cols, math.floor(x1 / grid.bin_width_m) + 1)
        r0 = max(0, math.floor(y0 / grid.bin_length_m))
        r1 = min(grid.rows, math.floor(y1 / grid.bin_length_m) + 1)
        if c0 >= c1 or r0 >= r1:
            return None
        return slice(r0 * s, r1 * s), slice(c0 * s, c1 * s)

    def _interference(self, contacts: Sequence[Contact], depths: Sequence[float], window) -> tuple[np.ndarray,
                                                                                                    np.ndarray]:
        """(interference, owner): max over indenters of depth - height (-inf where none), and which one wins."""
        rows, cols = window
        y = (np.arange(rows.start, rows.stop) + 0.5) * self.pixel_y_m
        x = (np.arange(cols.start, cols.stop) + 0.5) * self.pixel_x_m
        interference = np.full((y.size, x.size), -np.inf)
        owner = np.full((y.size, x.size), -1)
        for k, (contact, depth) in enumerate(zip(contacts, depths, strict=True)):
            height = _indenter_height_m(contact.shape, x[None, :] - contact.x_m, y[:, None] - contact.y_m)
            w = depth - height
            better = w > interference
            interference[better] = w[better]
            owner[better] = k
        return interference, owner

    # --- the solver ---------------------------------------------------------------------------------------------

    def _kernel_fft(self, rows: int, cols: int) -> np.ndarray:
        key = (rows, cols)
        if key not in self._kernels:
            if len(self._kernels) > 32:
                self._kernels.clear()
            kernel = surface_influence(self.layer, self.pixel_x_m, self.pixel_y_m, rows, cols)
            self._kernels[key] = np.fft.rfft2(kernel)
        return self._kernels[key]

    def solve_pressure(self, interference: np.ndarray) -> np.ndarray:
        """Pressure (Pa) >= 0 on a pixel window such that the surface displacement u >= interference, with
        equality where the pressure is positive (Polonsky and Keer 1999, displacement-controlled variant).

        `interference` is -inf where no indenter is; such pixels never carry pressure.
        """
        rows, cols = interference.shape
        candidate = interference > -np.inf
        if not np.any(interference > 0.0):
            return np.zeros_like(interference)
        kernel = self._kernel_fft(rows, cols)

        def displacement(pressure):
            return np.fft.irfft2(np.fft.rfft2(pressure, s=(2 * rows, 2 * cols)) * kernel,
                                 s=(2 * rows, 2 * cols))[:rows, :cols]

        target = np.where(candidate, interference, 0.0)
        self_influence = np.fft.irfft2(kernel, s=(2 * rows, 2 * cols))[0, 0]
        pressure = np.where(interference > 0.0, interference / self_influence, 0.0)
        direction = np.zeros_like(pressure)
        g_old, restart = 1.0, True
        for _ in range(self.max_iterations):
            gap = displacement(pressure) - target
            active = pressure > 0.0
            g_now = float(np.sum(gap[active] ** 2))
            direction = np.where(active, gap + (0.0 if restart else g_now / g_old) * direction, 0.0)
            g_old = g_now
            response = displacement(direction)
            curvature = float(np.sum(response[active] * direction[active]))
            if curvature <= 0.0:
                break
            step = float(np.sum(gap[active] * direction[active])) / curvature
            previous = pressure
            pressure = np.maximum(pressure - step * direction, 0.0)
            overlap = (pressure == 0.0) & (gap < 0.0) & candidate
            restart = bool(np.any(overlap))
            if restart:
                pressure[overlap] -= step * gap[overlap]
            change = np.sum(np.abs(pressure - previous))
            if change <= self.tolerance * np.sum(pressure):
                break
        return pressure

    # --- the model interface ------------------------------------------------------------------------------------

    def pixel_forces(self, contacts: Sequence[Contact]) -> tuple[np.ndarray, tuple[slice, slice]] | None:
        """(forces, window): (H, W, 3) newtons per surface pixel of the window (rows, cols slices of the surface
        pixel grid, whole bins), or None when nothing touches. What bin_forces sums per bin."""
        for contact in contacts:
            if not isinstance(contact, Contact):
                raise ValueError(f"contacts must hold Contact objects, got {type(contact).__name__}")
            check_contact(self.sensor, contact)
        pressing = [c for c in contacts if c.depth_m > 0.0]
        window = self._window(pressing) if pressing else None
        if window is None:
            return None
        interference, owner = self._interference(pressing, [c.depth_m for c in pressing], window)
        pressure = self.solve_pressure(interference)
        area = self.pixel_x_m * self.pixel_y_m
        forces = np.zeros(pressure.shape + (3,))
        forces[..., 2] = pressure * area

        stick_depths = [stick_depth_m(self.layer, c) for c in pressing]
        if any(d != c.depth_m for d, c in zip(stick_depths, pressing, strict=True)):
            stick, _ = self._interference(pressing, stick_depths, window)
            # q <= mu p holds in theory; the clip only removes solver round-off
            slip = np.clip(pressure - self.solve_pressure(stick), 0.0, pressure)
            for k, contact in enumerate(pressing):
                shear = math.hypot(*contact.shear_m)
                if shear == 0.0:
                    continue
                mine = owner == k
                q = contact.friction * slip[mine] * area
                forces[mine, 0] = q * contact.shear_m[0] / shear
                forces[mine, 1] = q * contact.shear_m[1] / shear
        return forces, window

    def bin_forces(self, contacts: Sequence[Contact]) -> np.ndarray:
        grid, s = self.sensor.grid, self.pixels_per_bin
        out = np.zeros((grid.rows, grid.cols, 3))
        solved = self.pixel_forces(contacts)
        if solved is None:
            return out
        forces, (rows, cols) = solved
        height, width = forces.shape[:2]
        out[rows.start // s:rows.stop // s, cols.start // s:cols.stop // s] = \
            forces.reshape(height // s, s, width // s, s, 3).sum(axis=(1, 3))
        return out


def _footprint_radius_m(shape, height_m: float) -> float:
    """Radius around the contact point inside which the indenter is less than height_m above its lowest point."""
    if isinstance(shape, Sphere):
        h = min(height_m, shape.radius_m)
        return math.sqrt(max(2.0 * shape.radius_m * h - h * h, 0.0))
    if isinstance(shape, FlatPunch):
        return shape.radius_m
    rows, cols = shape.heights_m.shape
    return 0.5 * math.hypot(rows, cols) * shape.pixel_m


def _indenter_height_m(shape, dx: np.ndarray, dy: np.ndarray) -> np.ndarray:
    """Height of the indenter surface above its lowest point at offsets (dx, dy); +inf where it is absent."""
    dx, dy = np.broadcast_arrays(dx, dy)
    if isinstance(shape, Sphere):
        r2 = dx * dx + dy * dy
        radius = shape.radius_m
        inside = r2 < radius * radius
        return np.where(inside, radius - np.sqrt(np.where(inside, radius * radius - r2, 0.0)), np.inf)
    if isinstance(shape, FlatPunch):
        return np.where(dx * dx + dy * dy <= shape.radius_m**2, 0.0, np.inf)
    if isinstance(shape, HeightMap):
        rows, cols = shape.heights_m.shape
        i = dy / shape.pixel_m + 0.5 * (rows - 1)
        j = dx / shape.pixel_m + 0.5 * (cols - 1)
        inside = (i >= 0) & (i <= rows - 1) & (j >= 0) & (j <= cols - 1)
        sampled = map_coordinates(shape.heights_m, [i.ravel(), j.ravel()], order=1, mode="nearest").reshape(dx.shape)
        return np.where(inside, sampled, np.inf)
    raise ValueError(f"unknown indenter shape {type(shape).__name__}")
