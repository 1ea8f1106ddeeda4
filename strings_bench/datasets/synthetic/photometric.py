"""Per-view photometric variation and sensor effects applied to a rendered view.

Real captures differ from view to view in exposure and white balance, darken towards the image
corners (vignetting), and carry blur and sensor noise. The ray caster renders none of that; this
module turns a clean render (float RGB in [0, 1], before quantisation) into the photo a camera
would have taken, in the order a camera forms it:

    optics: defocus (Gaussian, sd `defocus_px`), motion blur (a line of `motion_px` pixels at
            angle `motion_deg`), vignetting (gain 1 - v r^2, r = 1 at the image corners)
    sensor: exposure gain (2 ** stops) and white-balance gains (R, G, B; G = 1), Gaussian noise
            (sd `noise_sigma` in 8-bit levels), then clipping and rounding to 8 bits.

Only the images change: poses, GT text masks and annotations stay those of the clean render (the
text is where it is; a blurred or dark view shows it worse). The draws of each view come from their
own random stream (seed, view index), so they never disturb the scene content or the camera path.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy import ndimage


@dataclass(frozen=True)
class ViewPhotometry:
    """What one view's camera did: the parameters drawn for it (recorded in scene_meta.json)."""

    exposure_stops: float = 0.0  # image gain 2 ** stops
    wb_gains: tuple[float, float, float] = (1.0, 1.0, 1.0)  # per-channel gains (R, G, B), G fixed at 1
    vignetting: float = 0.0  # gain at the image corners is 1 - vignetting
    defocus_px: float = 0.0  # sd of the Gaussian defocus kernel, pixels
    motion_px: float = 0.0  # length of the linear motion-blur kernel, pixels
    motion_deg: float = 0.0  # its direction, degrees from the image x axis
    noise_sigma: float = 0.0  # sd of additive Gaussian noise, 8-bit levels

    def is_identity(self) -> bool:
        return self == ViewPhotometry()

    def as_dict(self) -> dict:
        d = asdict(self)
        d["wb_gains"] = list(d["wb_gains"])
        return d


def draw_view_photometry(settings, rng: np.random.Generator) -> ViewPhotometry:
    """One view's parameters from the generator settings' difficulty controls (see SyntheticSettings)."""
    stops = float(rng.normal(0.0, settings.exposure_sd)) if settings.exposure_sd > 0 else 0.0
    if settings.white_balance_sd > 0:
        r, b = np.exp(rng.normal(0.0, settings.white_balance_sd, 2))
        wb = (float(r), 1.0, float(b))
    else:
        wb = (1.0, 1.0, 1.0)
    if settings.motion_blur_px > 0:
        motion = float(settings.motion_blur_px * rng.uniform(0.0, 1.0))
        angle = float(rng.uniform(0.0, 180.0))
    else:
        motion, angle = 0.0, 0.0
    return ViewPhotometry(exposure_stops=stops, wb_gains=wb, vignetting=float(settings.vignetting),
                          defocus_px=float(settings.defocus_px), motion_px=motion, motion_deg=angle,
                          noise_sigma=float(settings.noise_sigma))


def motion_kernel(length_px: float, angle_deg: float) -> np.ndarray:
    """A normalised line kernel `length_px` long (sub-pixel ends weighted), centred, at `angle_deg`."""
    half = max(1, int(np.ceil(length_px / 2)) + 1)
    size = 2 * half + 1
    # Supersample the line: 8 samples per pixel along it, splatted bilinearly.
    n = max(2, int(np.ceil(8 * length_px)))
    s = (np.arange(n) + 0.5) / n - 0.5
    a = np.deg2rad(angle_deg)
    xs, ys = half + s * length_px * np.cos(a), half - s * length_px * np.sin(a)
    k = np.zeros((size, size))
    x0, y0 = np.floor(xs).astype(int), np.floor(ys).astype(int)
    fx, fy = xs - x0, ys - y0
    for dx, dy, w in ((0, 0, (1 - fx) * (1 - fy)), (1, 0, fx * (1 - fy)), (0, 1, (1 - fx) * fy), (1, 1, fx * fy)):
        np.add.at(k, (y0 + dy, x0 + dx), w)
    return k / k.sum()


def vignetting_gain(height: int, width: int, strength: float) -> np.ndarray:
    """(H, W) gain 1 - strength * r^2, r the distance from the image centre over the half-diagonal."""
    y = (np.arange(height) + 0.5 - height / 2) / (height / 2)
    x = (np.arange(width) + 0.5 - width / 2) / (width / 2)
    r2 = (x[None, :] ** 2 + y[:, None] ** 2) / 2.0  # = 1 at the corners
    return 1.0 - strength * r2


def apply_photometry(rgb: np.ndarray, view: ViewPhotometry, rng: np.random.Generator) -> np.ndarray:
    """The 8-bit photo of the clean float render `rgb` (H, W, 3 in [0, 1]) taken with `view`'s settings."""
    img = np.asarray(rgb, np.float64)
    if view.defocus_px > 0:
        img = ndimage.gaussian_filter(img, sigma=(view.defocus_px, view.defocus_px, 0), mode="reflect")
    if view.motion_px > 0.05:
        k = motion_kernel(view.motion_px, view.motion_deg)
        img = np.stack([ndimage.convolve(img[..., c], k, mode="reflect") for c in range(3)], axis=-1)
    if view.vignetting:
        img = img * vignetting_gain(img.shape[0], img.shape[1], view.vignetting)[..., None]
    img = img * (2.0 ** view.exposure_stops) * np.asarray(view.wb_gains, np.float64)
    img = img * 255.0
    if view.noise_sigma > 0:
        img = img + rng.normal(0.0, view.noise_sigma, img.shape)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)
