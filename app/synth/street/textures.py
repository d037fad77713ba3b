"""Procedural textures: grey facade/ground images (rich, non-repetitive detail for SIFT) and the
colour faces of traffic signs. Images are uint8; sign faces are BGR, as OpenCV writes them."""

from __future__ import annotations

import math

import cv2
import numpy as np

# Octaves of value noise, in texels per cell, with their relative amplitude.
_OCTAVES = ((256, 0.9), (96, 0.8), (32, 0.7), (12, 0.55), (4, 0.45), (1.5, 0.3))


def value_noise(rng: np.random.Generator, h: int, w: int, low_texture: bool) -> np.ndarray:
    """Multi-octave noise, float32 (h, w), roughly zero mean and unit spread."""
    # Coarse octaves are summed on a grid 4x smaller, then enlarged once: same look, less work.
    ch, cw = max(2, h // 4), max(2, w // 4)
    coarse = np.zeros((ch, cw), np.float32)
    out = np.zeros((h, w), np.float32)
    for cell, amp in _OCTAVES[:4] if low_texture else _OCTAVES:
        gh, gw = max(2, int(h / cell) + 2), max(2, int(w / cell) + 2)
        grid = rng.standard_normal((gh, gw), dtype=np.float32)
        # Resizing a coarse grid gives smooth noise whose cells do not line up across octaves.
        if cell >= 16:
            coarse += amp * cv2.resize(grid, (cw, ch), interpolation=cv2.INTER_CUBIC)
        else:
            out += amp * cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC)
    out += cv2.resize(coarse, (w, h), interpolation=cv2.INTER_LINEAR)
    return out


def crisp_noise(rng: np.random.Generator, h: int, w: int, cell: float) -> np.ndarray:
    """Sharp-edged random blobs about ``cell`` texels across, float32 in [-1, 1]: the corners and
    blobs SIFT locks onto, at every place different."""
    gh, gw = max(2, int(h / cell) + 2), max(2, int(w / cell) + 2)
    grid = rng.standard_normal((gh, gw), dtype=np.float32)
    return np.tanh(3.0 * cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC))


def _finish(img: np.ndarray, mean: float, contrast: float) -> np.ndarray:
    return np.clip(mean + contrast * img, 0, 255).astype(np.uint8)


def facade_texture(rng: np.random.Generator, width_m: float, height_m: float, texel_m: float,
                   low_texture: bool = False) -> np.ndarray:
    """A building front: noise plaster, floors of irregular windows, posters and stains."""
    w, h = max(4, int(round(width_m / texel_m))), max(4, int(round(height_m / texel_m)))
    img = value_noise(rng, h, w, low_texture) * 18.0
    px = 1.0 / texel_m
    floor_m = float(rng.uniform(2.8, 3.6))
    n_floors = int(height_m / floor_m)
    detail = 0.35 if low_texture else 1.0
    for f in range(n_floors):
        if rng.random() < 0.15:
            continue
        top = height_m - (f + 1) * floor_m + float(rng.uniform(0.5, 0.9))
        win_h = float(rng.uniform(1.1, 1.7))
        x = float(rng.uniform(0.3, 1.5))
        while x < width_m - 1.0:
            win_w = float(rng.uniform(0.7, 2.2))
            if x + win_w > width_m - 0.3:
                break
            if rng.random() < 0.85:
                x0, y0 = int(x * px), int((height_m - top - win_h) * px)
                x1, y1 = int((x + win_w) * px), int((height_m - top) * px)
                shade = float(rng.uniform(-70, 40)) * detail
                frame = max(1, int(rng.uniform(0.04, 0.12) * px))
                cv2.rectangle(img, (x0 - frame, y0 - frame), (x1 + frame, y1 + frame),
                              float(rng.uniform(20, 50)) * detail, -1)
                cv2.rectangle(img, (x0, y0), (x1, y1), shade, -1)
                # A curtain at a random height makes every window different.
                cy = int(y0 + rng.uniform(0.1, 0.9) * (y1 - y0))
                curtain = shade + float(rng.uniform(-30, 50)) * detail
                cv2.rectangle(img, (x0, y0), (x1, cy), curtain, -1)
            x += win_w + float(rng.uniform(0.5, 2.5))
    _scatter(rng, img, int(width_m * height_m / (12.0 if low_texture else 4.0)), px, detail)
    crisp = 1.0
    img += crisp * (22.0 * crisp_noise(rng, h, w, 3.0) + 18.0 * crisp_noise(rng, h, w, 9.0))
    contrast = 0.65 if low_texture else 1.0
    return _finish(cv2.GaussianBlur(img, (0, 0), 0.6), float(rng.uniform(110, 170)), contrast)


def surface_texture(rng: np.random.Generator, width_m: float, height_m: float, texel_m: float,
                    low_texture: bool = False) -> np.ndarray:
    """Painted metal or concrete: noise with a few stains, for props, poles and roofs."""
    w, h = max(4, int(round(width_m / texel_m))), max(4, int(round(height_m / texel_m)))
    img = value_noise(rng, h, w, low_texture) * 20.0
    detail = 0.35 if low_texture else 1.0
    img += (7.0 if low_texture else 20.0) * crisp_noise(rng, h, w, 3.0)
    _scatter(rng, img, int(width_m * height_m / 0.5) + 1, 1.0 / texel_m, detail)
    return _finish(img, float(rng.uniform(90, 180)), 0.3 if low_texture else 1.0)


def _scatter(rng, img, n, px, detail) -> None:
    """Posters, stains and blobs of random size and shade."""
    h, w = img.shape
    cx, cy = rng.integers(0, w, n), rng.integers(0, h, n)
    size = np.exp(rng.uniform(math.log(0.04), math.log(0.6), n)) * px
    ax = np.maximum(1, (size * rng.uniform(0.3, 1.0, n))).astype(int)
    ay = np.maximum(1, (size * rng.uniform(0.3, 1.0, n))).astype(int)
    shade = rng.uniform(-60, 60, n) * detail
    angle = rng.uniform(0, 180, n)
    is_rect = rng.random(n) < 0.5
    for i in range(n):
        x, y, a, b, c = int(cx[i]), int(cy[i]), int(ax[i]), int(ay[i]), float(shade[i])
        if is_rect[i]:
            cv2.rectangle(img, (x - a, y - b), (x + a, y + b), c, -1)
        else:
            cv2.ellipse(img, (x, y), (a, b), float(angle[i]), 0, 360, c, -1)


def ground_texture(rng: np.random.Generator, h: int, w: int, road_mask: np.ndarray,
                   texel_m: float, low_texture: bool = False) -> np.ndarray:
    """Asphalt (``road_mask`` > 0) and pavement/grass elsewhere, with cracks and patches."""
    img = value_noise(rng, h, w, low_texture) * 16.0
    detail = 0.35 if low_texture else 1.0
    img += (5.0 if low_texture else 14.0) * crisp_noise(rng, h, w, 2.5)
    _scatter(rng, img, int(h * w * texel_m * texel_m / (4.0 if low_texture else 1.0)), 1 / texel_m,
             detail * 0.6)
    base = np.where(road_mask > 0, 85.0, 135.0).astype(np.float32)
    img = base + img * (0.3 if low_texture else 1.0)
    return np.clip(cv2.GaussianBlur(img, (0, 0), 0.6), 0, 255).astype(np.uint8)


SIGN_STYLES = {
    # class: (shape, fill BGR, border BGR, text, text BGR)
    "stop": ("octagon", (35, 30, 200), (250, 250, 250), "STOP", (250, 250, 250)),
    "yield": ("triangle", (245, 245, 245), (40, 30, 205), "", (0, 0, 0)),
    "speed_limit_50": ("round", (245, 245, 245), (40, 30, 205), "50", (20, 20, 20)),
    "speed_limit_30": ("round", (245, 245, 245), (40, 30, 205), "30", (20, 20, 20)),
    "no_entry": ("round", (40, 30, 205), (40, 30, 205), "", (0, 0, 0)),
    "priority": ("diamond", (20, 200, 245), (245, 245, 245), "", (0, 0, 0)),
    "parking": ("square", (170, 90, 20), (245, 245, 245), "P", (245, 245, 245)),
}


def sign_outline(shape: str, size_m: float, n_per_edge: int = 12) -> np.ndarray:
    """Points on the plate's rim (K, 2) in plate coordinates: metres from the centre, u right,
    v up, as seen from the front. Edges are sampled densely because lens distortion bends them."""
    r = size_m / 2.0
    if shape == "round":
        a = np.linspace(0.0, 2 * math.pi, 8 * n_per_edge, endpoint=False)
        return r * np.column_stack([np.cos(a), np.sin(a)])
    return _densify(sign_polygon(shape, size_m), n_per_edge)


def sign_polygon(shape: str, size_m: float) -> np.ndarray:
    """Vertices (V, 2), counter-clockwise, of a polygonal plate; round plates are not polygons."""
    r = size_m / 2.0
    if shape == "square":
        return np.array([[-r, -r], [r, -r], [r, r], [-r, r]])
    if shape == "diamond":
        return np.array([[0, -r], [r, 0], [0, r], [-r, 0]], float)
    if shape == "triangle":  # point down, like a yield sign
        return np.array([[0, -r], [r, r * 0.75], [-r, r * 0.75]])
    if shape == "octagon":
        a = np.radians(22.5 + 45.0 * np.arange(8))
        # Flat to flat across is the plate size.
        return (r / math.cos(math.radians(22.5))) * np.column_stack([np.cos(a), np.sin(a)])
    raise ValueError(f"not a polygonal plate: {shape}")


def _densify(poly: np.ndarray, n: int) -> np.ndarray:
    t = np.linspace(0.0, 1.0, n, endpoint=False)[:, None]
    return np.vstack([a + t * (b - a) for a, b in zip(poly, np.roll(poly, -1, axis=0))])


def sign_texture(cls: str, size_m: float, texel_m: float) -> np.ndarray:
    """The plate's face (n, n, 3) BGR; rows go down the plate, columns to the right."""
    shape, fill, border, text, text_bgr = SIGN_STYLES[cls]
    n = int(round(size_m / texel_m))
    img = np.full((n, n, 3), 150, np.uint8)  # the plate's metal edge, outside the printed face

    def to_px(uv: np.ndarray) -> np.ndarray:
        px = (np.column_stack([uv[:, 0], -uv[:, 1]]) / size_m + 0.5) * n
        return np.round(px).astype(np.int32)

    rim = sign_outline(shape, size_m, 4)
    cv2.fillPoly(img, [to_px(rim)], border, lineType=cv2.LINE_AA)
    cv2.fillPoly(img, [to_px(rim * 0.8)], fill, lineType=cv2.LINE_AA)
    if cls == "no_entry":
        cv2.rectangle(img, (int(0.2 * n), int(0.42 * n)), (int(0.8 * n), int(0.58 * n)),
                      (245, 245, 245), -1)
    if text:
        thick = max(1, n // 25)
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, 1.0, thick)
        scale = 0.55 * n / tw
        (tw, th), _ = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, thick)
        cv2.putText(img, text, ((n - tw) // 2, (n + th) // 2), cv2.FONT_HERSHEY_SIMPLEX, scale,
                    text_bgr, max(1, n // 25), cv2.LINE_AA)
    return img


def mip_chain(img: np.ndarray, levels: int) -> list[np.ndarray]:
    """The image and up to ``levels - 1`` Gaussian-filtered halvings (cv2.pyrDown)."""
    chain = [img]
    while len(chain) < levels and min(chain[-1].shape[:2]) >= 4:
        chain.append(cv2.pyrDown(chain[-1]))
    return chain
