"""Does a rendered journey's imagery fit its own true camera? (``signmap bench render-check``)

A self-calibration figure from a render is only as good as the render: if the renderer drew the
world through a lens other than the one its truth file names, every calibration error the corpus
bench reports would be partly the renderer's. This measures it without any SfM: SIFT matches
between pairs of frames in the journey's sharpest turn are triangulated with the TRUE poses
(``truth.json``'s ``T_world_cam``, camera to world, OpenCV camera axes) and projected back
through the true camera with fx and fy scaled by each of ``SCALES``. A faithful render fits best
at scale 1; the mean error's rise at 0.99 and 1.01 says how sharply the imagery alone pins the
focal length once the poses are known.
"""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from datetime import date
from pathlib import Path

import cv2
import numpy as np

from app.pipeline.geometry.triangulation import undistort_pixels
from app.pipeline.types import CameraModel

SCALES = (0.98, 0.99, 0.995, 1.0, 1.005, 1.01, 1.02)
MAX_ERROR_PX = 3.0  # matches further off than this at any scale are wrong matches, not signal


@dataclass(frozen=True)
class PairMatches:
    """Matched pixels (N, 2) of frames ``i`` and ``j``, with their true poses (4, 4)."""

    i: int
    j: int
    T_world_cam_i: np.ndarray
    T_world_cam_j: np.ndarray
    px_i: np.ndarray
    px_j: np.ndarray


@dataclass(frozen=True)
class FocalScan:
    """Mean reprojection error (px) of the matches at each focal ``scales`` (S,)."""

    scales: np.ndarray
    mean_px: np.ndarray
    n_matches: int

    @property
    def best_scale(self) -> float:
        """The vertex of the parabola through the lowest point and its two neighbours."""
        k = int(np.clip(np.argmin(self.mean_px), 1, len(self.scales) - 2))
        x, y = self.scales[k - 1:k + 2], self.mean_px[k - 1:k + 2]
        a, b, _ = np.polyfit(x, y, 2)
        return float(-b / (2 * a)) if a > 0 else float(self.scales[np.argmin(self.mean_px)])

    def at(self, scale: float) -> float:
        return float(self.mean_px[int(np.argmin(np.abs(self.scales - scale)))])


def turn_pairs(T_world_cam: np.ndarray, n_pairs: int,
               step_deg: float = 2.0) -> list[tuple[int, int]]:
    """Up to ``n_pairs`` frame pairs (i, j) around the sharpest heading change of the poses
    ``T_world_cam`` (N, 4, 4), each pair turning about ``step_deg``."""
    forward = T_world_cam[:, :3, 2]
    heading = np.unwrap(np.arctan2(forward[:, 1], forward[:, 0]))
    rate_deg = np.degrees(np.abs(np.gradient(heading)))
    centre = int(np.argmax(np.convolve(rate_deg, np.ones(9) / 9, mode="same")))
    gap = int(np.clip(round(step_deg / max(rate_deg[centre], 1e-6)), 1, 10))
    starts = [centre + gap * k for k in range(-n_pairs // 2, n_pairs - n_pairs // 2)]
    return [(i, i + gap) for i in starts if 0 <= i and i + gap < len(T_world_cam)]


def sift_matches(gray_i: np.ndarray, gray_j: np.ndarray, *, max_features: int = 4000,
                 ratio: float = 0.7) -> tuple[np.ndarray, np.ndarray]:
    """Lowe-ratio SIFT matches between two images: pixels (N, 2) in each."""
    sift = cv2.SIFT_create(max_features)
    kp_i, d_i = sift.detectAndCompute(gray_i, None)
    kp_j, d_j = sift.detectAndCompute(gray_j, None)
    if d_i is None or d_j is None:
        return np.zeros((0, 2)), np.zeros((0, 2))
    good = [m for m, n in cv2.BFMatcher().knnMatch(d_i, d_j, k=2)
            if m.distance < ratio * n.distance]
    return (np.float32([kp_i[m.queryIdx].pt for m in good]).reshape(-1, 2),
            np.float32([kp_j[m.trainIdx].pt for m in good]).reshape(-1, 2))


def _errors_px(pair: PairMatches, camera: CameraModel) -> np.ndarray:
    """Per match, the larger of its two reprojection errors (px) after triangulating it with the
    pair's true poses; inf behind either camera. The undistortion is the pipeline's, whose tight
    criteria matter here: OpenCV's default 5 iterations leave the corners of wide lenses short of
    their place, which reads as a focal error (c0850, 92 deg: best scale 1.017, not 1.002)."""
    P = [np.linalg.inv(T)[:3] for T in (pair.T_world_cam_i, pair.T_world_cam_j)]
    px = (pair.px_i, pair.px_j)
    K, dist = camera.K, camera.dist
    n = [(undistort_pixels(camera, p) - K[:2, 2]) / np.diag(K)[:2] for p in px]
    X_h = cv2.triangulatePoints(P[0], P[1], n[0].T, n[1].T)
    p_world = (X_h[:3] / X_h[3]).T
    worst = np.zeros(len(p_world))
    for P_cam_world, p in zip(P, px):
        p_cam = p_world @ P_cam_world[:, :3].T + P_cam_world[:, 3]
        proj, _ = cv2.projectPoints(p_cam, np.zeros(3), np.zeros(3), K, dist)
        err = np.linalg.norm(proj.reshape(-1, 2) - p, axis=1)
        worst = np.maximum(worst, np.where(p_cam[:, 2] > 0.1, err, np.inf))
    return worst


def focal_scan(pairs: list[PairMatches], camera: dict, scales=SCALES) -> FocalScan:
    """The pairs' matches scored through ``camera`` (truth.json's: fx, fy, cx, cy, k1, k2 in
    OpenCV's pixel convention) with fx and fy times each of ``scales``. Only matches within
    MAX_ERROR_PX at every scale count, so each scale is scored on the same matches."""
    true = CameraModel(**camera)
    errors = []
    for s in scales:
        scaled = true.replace(fx=true.fx * s, fy=true.fy * s)
        errors.append(np.concatenate([_errors_px(p, scaled) for p in pairs]) if pairs
                      else np.zeros(0))
    errors = np.array(errors)
    kept = np.all(errors < MAX_ERROR_PX, axis=0)
    mean = errors[:, kept].mean(axis=1) if kept.any() else np.full(len(scales), np.nan)
    return FocalScan(np.asarray(scales, float), mean, int(kept.sum()))


def check_journey(journey_dir: Path, n_pairs: int = 8) -> tuple[FocalScan, dict]:
    """``focal_scan`` of a rendered journey directory (``bundle.zip`` and ``truth.json``)."""
    truth = json.loads((journey_dir / "truth.json").read_text())
    return check_bundle(journey_dir / "bundle.zip", truth, n_pairs), truth


def check_bundle(bundle: Path, truth: dict, n_pairs: int = 8) -> FocalScan:
    """``focal_scan`` of ``n_pairs`` pairs of a journey's bundle, with its truth file's poses."""
    T_world_cam = np.array([f["T_world_cam"] for f in truth["frames"]], float)
    with zipfile.ZipFile(bundle) as z:
        members = {Path(n).stem: n for n in z.namelist() if n.startswith("frames/")}

        def gray(i: int) -> np.ndarray:
            data = np.frombuffer(z.read(members[truth["frames"][i]["frame"]]), np.uint8)
            return cv2.imdecode(data, cv2.IMREAD_GRAYSCALE)

        pairs = []
        for i, j in turn_pairs(T_world_cam, n_pairs):
            px_i, px_j = sift_matches(gray(i), gray(j))
            pairs.append(PairMatches(i, j, T_world_cam[i], T_world_cam[j], px_i, px_j))
    return focal_scan(pairs, truth["camera"])


def run_render_check(corpus_dir: Path, names: list[str] | None, out_dir: Path) -> Path:
    """One row per journey of the corpus (or ``names``); writes and returns the markdown table."""
    index = json.loads((corpus_dir / "corpus.json").read_text())
    journeys = [j for j in index["journeys"] if names is None or j["name"] in names]
    lines = ["| journey | k1 | hfov ° | W×H | matches | best focal scale | mean px at "
             "0.99 / 1.00 / 1.01 |", "| --- | --- | --- | --- | --- | --- | --- |"]
    for j in journeys:
        scan, truth = check_journey(corpus_dir / j["name"])
        p = j["params"]
        lines.append(f"| {j['name']} | {p['k1']:+.3f} | {p['hfov_deg']:.0f} | "
                     f"{p['width']}×{p['height']} | {scan.n_matches} | {scan.best_scale:.4f} | "
                     f"{scan.at(0.99):.3f} / {scan.at(1.0):.3f} / {scan.at(1.01):.3f} |")
        print(lines[-1], flush=True)
    out_dir.mkdir(parents=True, exist_ok=True)
    md = out_dir / f"{date.today().isoformat()}-render-check.md"
    md.write_text("# Render check: SIFT matches triangulated with the true poses\n\n"
                  f"Corpus `{corpus_dir}`; `bench/studies/render_check.py` says how.\n\n"
                  + "\n".join(lines) + "\n")
    return md


__all__ = ["FocalScan", "PairMatches", "check_bundle", "check_journey", "focal_scan",
           "run_render_check", "sift_matches", "turn_pairs"]
