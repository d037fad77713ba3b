"""Typed values that flow between the pipeline steps.

Conventions, stated once for the whole pipeline:

* Pixels follow OpenCV: the centre of the top-left pixel is (0, 0); x right, y down. (COLMAP puts
  pixel centres at +0.5; only ``app.pipeline.colmap`` converts, at the boundary.)
* Camera frame ``cam``: x right, y down, z forward (OpenCV / the rectified camera of the contract).
* World frame ``enu``: a local East-North-Up tangent plane in metres, origin at the journey's first
  GPS fix (see ``app.pipeline.geometry.geodesy``).
* A pose ``T_a_b`` maps points from frame b into frame a: ``p_a = R_a_b @ p_b + t_a_b``. Poses are
  4x4 float64 arrays; stacks of them have shape (N, 4, 4).
* Lens model: pinhole with zero skew and two-coefficient radial distortion (the paper's eq. 1-2,
  OpenCV's ``k1, k2`` with ``p1 = p2 = k3 = 0``; COLMAP's OPENCV model with ``p1 = p2 = 0``).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable

import numpy as np

if TYPE_CHECKING:  # geometry imports these types; the annotation needs only the name
    from app.pipeline.geometry.uncertainty import GeorefTerms


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics and radial distortion of one physical camera, in pixels of the original image."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    k1: float = 0.0
    k2: float = 0.0

    @property
    def K(self) -> np.ndarray:
        """3x3 camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist(self) -> np.ndarray:
        """OpenCV distortion vector (k1, k2, p1, p2)."""
        return np.array([self.k1, self.k2, 0.0, 0.0])

    def params(self) -> dict[str, float]:
        """The six calibration parameters, as the contract's ``calibration`` object."""
        return {k: float(getattr(self, k)) for k in ("fx", "fy", "cx", "cy", "k1", "k2")}

    def replace(self, **changes: float) -> "CameraModel":
        return dataclasses.replace(self, **changes)

    @classmethod
    def from_params(cls, width: int, height: int, params: dict[str, float]) -> "CameraModel":
        return cls(width=width, height=height, **{k: float(params.get(k, 0.0)) for k in
                                                   ("fx", "fy", "cx", "cy", "k1", "k2")})


@dataclass(frozen=True)
class Frame:
    """One camera frame of a journey; ``path`` is the image file on local disk."""

    frame_id: str
    path: Path
    timestamp_s: float


@dataclass(frozen=True)
class Detection:
    """A sign detection in one frame; the box is in the ORIGINAL (distorted) image, OpenCV pixels."""

    frame_id: str
    track_id: str
    cls: str
    x1: float
    y1: float
    x2: float
    y2: float
    score: float | None = None

    @property
    def centre_px(self) -> tuple[float, float]:
        return (0.5 * (self.x1 + self.x2), 0.5 * (self.y1 + self.y2))


@dataclass(frozen=True)
class GpsTrack:
    """The GPS fixes a journey's frame positions were interpolated from, in time order: arrays
    (M,); ``alt_m`` NaN where a fix has none."""

    timestamp_s: np.ndarray
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_m: np.ndarray


@dataclass(frozen=True)
class AntennaOffset:
    """Where the GPS antenna sits relative to the camera: the antenna's position minus the
    camera's, metres, in the vehicle's axes (forward along the direction of travel, left, up; the
    manifest's ``gps_antenna_offset_m``). ``geometry.gps_track.camera_positions`` applies it.
    ``source``: who said so, in the align stage's report ("manifest", "vehicle van-3")."""

    forward_m: float
    left_m: float
    up_m: float
    source: str = "manifest"


@dataclass(frozen=True)
class AntennaEstimate:
    """A horizontal GPS antenna offset that turns told (``geometry.antenna``) where nobody declared
    one: forward and left (m, vehicle axes, as ``AntennaOffset``) and their 1-sigma (m), from
    ``n_journeys`` journeys (``combined``)."""

    forward_m: float
    left_m: float
    sigma_forward_m: float
    sigma_left_m: float
    n_journeys: int = 1

    @property
    def sigma_m(self) -> float:
        return max(self.sigma_forward_m, self.sigma_left_m)

    def offset(self, source: str) -> AntennaOffset:
        return AntennaOffset(self.forward_m, self.left_m, 0.0, source)

    def to_json(self) -> dict:
        return {"forward_m": self.forward_m, "left_m": self.left_m,
                "sigma_forward_m": self.sigma_forward_m, "sigma_left_m": self.sigma_left_m,
                "n_journeys": self.n_journeys}

    @classmethod
    def from_json(cls, data: dict) -> "AntennaEstimate":
        return cls(float(data["forward_m"]), float(data["left_m"]),
                   float(data["sigma_forward_m"]), float(data["sigma_left_m"]),
                   int(data.get("n_journeys", 1)))

    @classmethod
    def combined(cls, estimates: "list[AntennaEstimate]") -> "AntennaEstimate | None":
        """Per axis, the inverse-variance mean of ``estimates`` and its sigma: journeys driven at
        other times share no GPS error, so their estimates are independent; None for none."""
        if not estimates:
            return None
        axes = []
        for value, sigma in (("forward_m", "sigma_forward_m"), ("left_m", "sigma_left_m")):
            weights = [1.0 / getattr(e, sigma) ** 2 for e in estimates]
            axes.append((sum(w * getattr(e, value) for w, e in zip(weights, estimates))
                         / sum(weights), sum(weights) ** -0.5))
        return cls(axes[0][0], axes[1][0], axes[0][1], axes[1][1],
                   sum(e.n_journeys for e in estimates))


@dataclass
class Journey:
    """A validated journey bundle, ready for the pipeline.

    ``lat_deg``, ``lon_deg``, ``alt_m`` are GPS positions interpolated to each frame's timestamp,
    shape (N,), aligned with ``frames``. ``alt_m`` is NaN everywhere when no altitude was uploaded.
    """

    camera_id: str
    frames: list[Frame]
    lat_deg: np.ndarray
    lon_deg: np.ndarray
    alt_m: np.ndarray
    detections: list[Detection]
    image_width: int
    image_height: int
    vehicle_id: str | None = None
    captured_at: str | None = None
    camera_prior: CameraModel | None = None
    # What validation tolerated but the uploader should know (e.g. frames dropped for lack of GPS).
    warnings: list[str] = field(default_factory=list)
    # White-noise sigma (m, per horizontal axis) of the GPS fixes, None when too few to tell
    # (geometry.gps_noise).
    gps_noise_m: float | None = None
    # The horizontal accuracy the receiver states for its fixes (68 % radius, m; the median over
    # the journey), None when the bundle gives none (``bundle.gps``).
    gps_accuracy_m: float | None = None
    # The fixes themselves (None: one EXIF fix per frame, which lat_deg etc. already are).
    gps_fixes: GpsTrack | None = None
    # What reading the bundle did that the journey's report should show first (a video's frame
    # choice and clock offset), as the stages' own reports.
    intake: tuple["StageReport", ...] = ()
    # The GPS antenna's position minus the camera's in vehicle axes (forward, left, up), as the
    # manifest declares it; None: the GPS position is the camera's.
    gps_antenna_offset: AntennaOffset | None = None
    # Without a declared offset: what the same vehicle's earlier journeys estimated, combined
    # (``AntennaEstimate.combined``), and whose it is for the align report ("vehicle van-3").
    antenna_prior: AntennaEstimate | None = None
    antenna_prior_source: str = ""

    @property
    def has_altitude(self) -> bool:
        return bool(np.all(np.isfinite(self.alt_m)))

    @property
    def frame_ids(self) -> list[str]:
        return [f.frame_id for f in self.frames]

    @property
    def timestamps_s(self) -> np.ndarray:
        """(N,) the frames' timestamps, seconds."""
        return np.array([f.timestamp_s for f in self.frames])


# The intrinsics ``Calibration.intrinsics_std`` gives stage 2's standard deviations of, in order.
INTRINSICS_STD = ("fx", "fy", "cx", "cy", "k1", "k2")


# ``Calibration.source`` of a journey given the camera's stored calibration (checked or not).
STORED_SOURCES = ("supplied", "checked")


@dataclass(frozen=True)
class Calibration:
    """Outcome of self-calibration (or of reusing a stored calibration).

    ``source`` is ``"self"`` when this journey calibrated itself, ``"checked"`` when its turn
    confirmed an earlier calibration of the same ``camera_id`` (``cameras.check_on_turn``), which
    ``camera`` is, and ``"supplied"`` when that earlier calibration was used unchecked (the
    journey has no turn, or could not calibrate). (The manifest's camera hint only seeds
    self-calibration's first focal length.)
    """

    camera: CameraModel
    source: str
    measured: CameraModel | None = None  # "checked": the checked window's own stage-2 camera
    stage1: CameraModel | None = None
    n_images: int = 0
    n_registered: int = 0
    reprojection_error_px: float = float("nan")
    rotation_deg: float = 0.0
    windows: list[tuple[int, int]] = field(default_factory=list)
    # Why a self-calibration was trusted: "reprojection" (one window under the sharp-image
    # error), "agreement" (two windows landed on the same camera) or "agreement on shared road".
    evidence: str = ""
    focal_std_rel: float = float("nan")  # stage 2's sigma(fx) / fx from its covariance
    # Stage 2's sigma of each of INTRINSICS_STD (px for fx, fy, cx, cy) from its covariance;
    # () when unknown.
    intrinsics_std: tuple[float, ...] = ()
    # The accepted window's reconstruction, for a camera's joint calibration
    # (``cameras.calibrate_jointly``); None when not kept (a stored calibration).
    observations: "WindowObservations | None" = None

    @property
    def turn_estimate(self) -> CameraModel | None:
        """What this journey's own turn measured of the camera; None: it measured nothing."""
        return self.camera if self.source == "self" else self.measured


@dataclass(frozen=True)
class WindowObservations:
    """A calibrated window's reconstruction, all that adjusting it again needs: ``T_cam_model``
    (M, 4, 4) its registered images' poses in its own model frame and scale; ``xyz_model`` (P, 3)
    its points; ``xy_px`` (N, 2) every observation, of point ``obs_point`` (N,) in image
    ``obs_image`` (N,) (indices into those). ``label``: which journey and frames it is."""

    label: str
    T_cam_model: np.ndarray
    xyz_model: np.ndarray
    xy_px: np.ndarray
    obs_image: np.ndarray
    obs_point: np.ndarray

    def arrays(self) -> dict[str, np.ndarray]:
        """The fields as arrays (``np.savez``); ``from_arrays`` inverts it."""
        return {"label": np.array(self.label), "T_cam_model": self.T_cam_model,
                "xyz_model": self.xyz_model, "xy_px": self.xy_px,
                "obs_image": self.obs_image, "obs_point": self.obs_point}

    @classmethod
    def from_arrays(cls, a) -> "WindowObservations":
        return cls(str(a["label"]), np.asarray(a["T_cam_model"], float),
                   np.asarray(a["xyz_model"], float), np.asarray(a["xy_px"], float),
                   np.asarray(a["obs_image"], np.int64), np.asarray(a["obs_point"], np.int64))


@dataclass(frozen=True)
class SignObservation:
    """The sign's position in one observing frame's camera, metres (x right, y down, z forward)."""

    frame_id: str
    p_cam: tuple[float, float, float]


@dataclass(frozen=True)
class SignUncertainty:
    """Where a sign's ``cov_enu`` comes from (``geometry.uncertainty``): the triangulation's own
    (3, 3) m^2 and the georeferencing terms (``GeorefTerms``) the knobs weighed."""

    cov_triangulation_enu: np.ndarray
    georef: GeorefTerms


@dataclass
class Sign:
    """One triangulated sign of a journey."""

    track_id: str
    cls: str
    xyz_enu: np.ndarray  # (3,) metres in the journey's ENU frame
    lat_deg: float
    lon_deg: float
    alt_m: float | None
    std_m: float  # 1-sigma position uncertainty (sqrt of cov_enu's largest eigenvalue)
    reprojection_rms_px: float
    observations: list[SignObservation]
    facing_deg: float | None = None  # compass bearing of the face (geometry.facing)
    # (3, 3) m^2 in the journey's ENU frame, triangulation + georeferencing (geometry.uncertainty)
    cov_enu: np.ndarray | None = None
    r95_h_m: float | None = None  # horizontal radius holding the true position with 95 % probability
    uncertainty: SignUncertainty | None = None


@dataclass(frozen=True)
class RejectedSign:
    track_id: str
    cls: str
    reason: str


@dataclass(frozen=True)
class WindowTime:
    """One COLMAP window's wall time: ``stage`` calibrate or ego_motion, ``frames`` its journey
    frames ("12-125"), images asked for and registered, seconds mapping it (``refine_s`` of
    which self-calibration's stage 2)."""

    stage: str
    frames: str
    n_images: int
    n_registered: int
    mapping_s: float
    refine_s: float = 0.0


@dataclass
class JourneyResult:
    """Everything the pipeline produces for one journey."""

    calibration: Calibration
    signs: list[Sign]
    rejected: list[RejectedSign]
    timings_s: dict[str, float]
    # Estimated (aligned) camera centres and the GPS positions they were aligned to, ENU metres,
    # for the frames that have a pose; shapes (M,3), frame ids of length M.
    trajectory_frame_ids: list[str] = field(default_factory=list)
    trajectory_enu: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    # The aligned camera poses of those frames, (M, 4, 4) T_world_cam in the same ENU frame
    # (change detection needs where each frame looked, not only where it was).
    trajectory_T_world_cam: np.ndarray = field(default_factory=lambda: np.zeros((0, 4, 4)))
    gps_enu: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    origin_lat_lon_alt: tuple[float, float, float] = (0.0, 0.0, 0.0)
    report: list["StageReport"] = field(default_factory=list)  # one per stage that ran, in order
    # Where a stage's seconds went, by part: calibrate and ego_motion's ``extract``/``match``
    # (SIFT) or ``klt``/``import``/``verify``, ``map`` (its windows side by side), ``refine``
    # (of map: self-calibration's stage 2), ``wait`` and ``map_idle_core_s`` (``colmap.sfm``).
    stage_parts_s: dict[str, dict[str, float]] = field(default_factory=dict)
    window_times: list[WindowTime] = field(default_factory=list)  # every window mapped, in order
    # This journey's own estimate of its undeclared GPS antenna offset (None: declared, or its
    # windows did not turn enough), kept so that a vehicle's journeys can be combined.
    antenna_estimate: AntennaEstimate | None = None
    broken_windows: list[BrokenWindow] = field(default_factory=list)


@dataclass(frozen=True)
class BrokenWindow:
    """An ego-motion window whose own alignment disagreed with the GPS beyond ``limit_m`` (the
    align stage): journey frames ``first_frame``..``last_frame``, its GPS rms (m), whether it
    was mended and how (``steps.align.mend``), and the sign tracks with a frame in it."""

    first_frame: int
    last_frame: int
    rms_m: float
    limit_m: float
    mended: bool
    how: str
    track_ids: tuple[str, ...] = ()


@dataclass(frozen=True)
class StageReport:
    """What one stage tried and how it ended, for the journey page and the CLI's JSON report
    (OpenSfM's per-step reports): ``summary`` one line, ``details`` one line per thing tried
    (a candidate window and why it was refused, a window's registration, a rejected track)."""

    stage: str
    summary: str
    details: tuple[str, ...] = ()

    def to_json(self) -> dict:
        return {"stage": self.stage, "summary": self.summary, "details": list(self.details)}

    @classmethod
    def from_json(cls, data: dict) -> "StageReport":
        return cls(str(data["stage"]), str(data["summary"]),
                   tuple(str(d) for d in data.get("details", ())))


def no_progress(stage: str, fraction: float, message: str = "") -> None:
    """A ProgressFn that ignores updates."""


class PipelineError(Exception):
    """A journey cannot be processed; ``stage`` names the step, the message says why."""

    def __init__(self, stage: str, reason: str):
        super().__init__(f"{stage}: {reason}")
        self.stage = stage
        self.reason = reason
        # The reports of the stages that ran before the failure, the failing one's last
        # (``process_journey`` fills this in): why every candidate was refused, and so on.
        self.report: list[StageReport] = []
        # Seconds per stage that ran, the failing one's included (its clock fills this in): a
        # calibration that refused every candidate took the longest of all, and a median over
        # the journeys that succeeded hides it.
        self.timings_s: dict[str, float] = {}


class NoTurnError(PipelineError):
    """The journey has no turn to calibrate on and no camera was known. ``finding`` says what was
    looked at; the reason goes on in the service's words (upload a journey with a turn first),
    which ``signmap process`` replaces with its own (``--calibration``)."""

    def __init__(self, finding: str):
        super().__init__("calibrate", f"{finding}; a straight road cannot calibrate the camera. "
                         "Upload a journey with a turn first, or supply a calibration for this "
                         "camera_id")
        self.finding = finding


class BundleError(PipelineError):
    """The uploaded bundle violates the wire contract; the message tells the user what to fix."""

    def __init__(self, reason: str):
        super().__init__("validate", reason)


ProgressFn = Callable[[str, float, str], None]
"""Called as the pipeline advances: stage name, overall fraction done in [0, 1], a message."""
