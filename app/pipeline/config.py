"""Knobs of the journey pipeline. Part of the one settings object (``app.settings.Settings.pipeline``,
environment ``SIGNMAP_PIPELINE__<NAME>``); every knob has a default that works on the synthetic
journeys and on KITTI-like footage. A comment says why a default is what it is and links the
decision that chose it; options measured and not taken are not here (docs/decisions/README.md)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field


class PipelineConfig(BaseModel):
    # The paper's scaled Mercator (eq. 3-4) is kept for comparison with its figures.
    metric_frame: Literal["enu", "mercator"] = "enu"

    # Turn finding, RDP on the metric GPS track (docs/decisions/turn-finding.md).
    # Measured best on the turn-finding bench (docs/decisions/rdp-tolerance.md).
    rdp_tolerance_m: float = Field(2.0, description="RDP tolerance on the metric GPS track")
    turn_smoothing_s: float = Field(
        1.0, description="seconds the GPS track is smoothed over before RDP (phones zigzag)")
    # Fast journeys with sparse GPS keep their turns (docs/decisions/turn-finding.md).
    turn_smoothing_max_m: float = Field(
        12.0, description="... but at most this many metres at the mean speed; 0: no cap")
    turn_min_angle_deg: float = Field(30.0, description="heading change that counts as a turn")
    turn_window_m: float = Field(40.0, description="track kept before and after a turn vertex, m")
    # Journeys whose GPS hid their turn calibrate (docs/decisions/turn-finding.md).
    turn_image_look: bool = Field(
        True, description="before refusing a journey \"no turn\", look for one on its images")
    turn_image_interval_s: float = Field(0.1, description="image look: seconds between frames")
    turn_image_max_frames: int = Field(400, description="image look: most frames read")
    turn_image_width_px: int = Field(640, description="image look: frames scaled to this width")
    turn_image_min_angle_deg: float = Field(
        30.0, description="image look: heading change (at the first focal guess) that is a turn")

    # Self-calibration's candidate windows (docs/decisions/calib-window-images.md).
    # Longer windows fell into more wrong minima (docs/decisions/calib-window-max-m.md).
    calib_window_m: float = Field(36.0, description="road a calibration candidate spans, metres")
    # Wide curves whose ordinary windows all failed (docs/decisions/calib-whole-curve.md).
    calib_long_window_max_m: float = Field(
        150.0, description="last, one candidate per wide curve spanning all of it plus "
        "calib_window_m, up to this many metres (0: none)")
    calib_long_window_images: int = Field(33, description="images a whole-curve candidate maps")
    # A fast U-turn registered every image (docs/decisions/calib-window-images.md).
    calib_rotation_share: float = Field(
        0.5, ge=0.0, le=1.0, description="share of a candidate's images spread by heading change "
        "rather than by distance")
    calib_images: int = Field(22, description="images a calibration candidate maps")
    calib_min_images: int = Field(12, description="fewest images a candidate maps")
    # Low frame rates at speed left fx loose (docs/decisions/calib-window-min-frames.md).
    calib_window_min_frames: int = Field(
        22, description="frames a candidate's road holds at least (the window grows)")
    calib_max_candidates: int = Field(
        7, description="ordinary candidate windows tried per journey (most stop at the first)")
    # KLT calibrated faster but less accurately (docs/decisions/klt-ego-motion.md).
    calib_front_end: Literal["klt", "sift"] = Field(
        "sift", description="how self-calibration finds correspondences")
    calib_initial_focal_factor: float = Field(
        0.8, description="first focal guess as a multiple of the image width (dash cams are wide)")
    # Lenses far from the first guess register (docs/decisions/calib-focal-retries.md).
    calib_retry_focal_factors: tuple[float, ...] = Field(
        (0.5, 1.2), description="focal guesses (x width) a poorly registered candidate is mapped "
        "again from")
    # The same cameras, faster (docs/decisions/calib-sift-features.md).
    calib_share_features: bool = Field(
        True, description="extract each frame's SIFT once for all calibration candidates")
    # Wide lenses' corners need k2 before stage 2 (docs/decisions/stage1-k2.md).
    calib_stage1_k2: bool = Field(
        True, description="stage 1 maps k1 and k2 (COLMAP RADIAL), not the paper's k1 alone")

    # Self-calibration's acceptance (docs/decisions/calib-lone-gates.md).
    # Lower bars cost more time than they gained (docs/decisions/calib-accept-reprojection-px.md).
    calib_accept_reprojection_px: float = Field(
        0.35, description="a candidate this good (after stage 2) ends the search early")
    # A wrong minimum registers a few frames or all (docs/decisions/calib-min-registered-ratio.md).
    calib_min_registered_ratio: float = Field(
        0.6, description="a candidate window must register this share of its frames")
    # Registering more is no sign of being right (docs/decisions/calib-focal-retries.md).
    calib_retry_below_ratio: float = Field(
        0.6, description="a candidate registering less than this share is mapped again from "
        "calib_retry_focal_factors; the mapping registering most is kept")
    # Half the corpus bar: refuses loose windows (docs/decisions/calib-max-focal-std.md).
    calib_max_focal_std: float = Field(
        0.005, description="refuse a candidate whose fx stage 2 leaves looser than this (0: never)")
    # Free fx and fy drifted apart by up to 5 % (docs/decisions/calib-aspect-prior.md).
    calib_aspect_prior_sigma: float = Field(
        0.005, description="stage 2: prior that pixels are square, relative sigma (0: none)")
    # Turning little, a narrow lens pins fx poorly (docs/decisions/calib-alone-min-rotation.md).
    calib_alone_min_rotation_deg: float = Field(
        45.0, description="a candidate turning less than this needs another window to agree")
    # Two sharp windows that disagree are not both right (docs/decisions/calib-alone-consistent.md).
    calib_alone_consistent: bool = Field(
        True, description="a candidate contradicting a sharp window kept before it needs another "
        "window to agree")
    # A focal length far too short turns too far (docs/decisions/calib-gps-rotation-check.md).
    calib_gps_rotation_check: bool = Field(
        True, description="refuse a candidate turning further than the GPS track, beyond a slack")
    calib_gps_chord_m: float = Field(10.0, description="GPS chords measuring a window's turn, m")
    calib_gps_rotation_sigmas: float = Field(
        3.0, description="slack of the GPS rotation check, in sigmas of the GPS heading change")
    calib_gps_rotation_min_slack_deg: float = Field(10.0, description="least slack, degrees")
    # Fast U-turns whose windows all share one road (docs/decisions/calib-shared-road.md).
    calib_shared_road_max_px: float = Field(
        0.45, ge=0.0, description="last resort: two agreeing windows of one road fitting under "
        "this error (px) are accepted (0: never)")
    calib_agreement: float = Field(
        0.015, description="two windows agree when fx, fy (and cx, cy per width) agree this well")

    # Feature extraction and matching (COLMAP).
    sift_max_features: int = 2048
    sift_max_image_size: int = 1600
    # Calibration as good at 3-5x the speed (docs/decisions/sift-first-octave.md).
    sift_first_octave: int = Field(0, description="-1 upsamples the image: more features, slower")
    # Small images have too few features at their own scale (docs/decisions/sift-first-octave.md).
    sift_upsample_below_px: int = Field(
        1000, description="images narrower than this are upsampled 2x for SIFT (octave -1)")
    match_overlap: int = Field(8, description="sequential matching: temporal neighbours per frame")
    colmap_threads: int = Field(2, description="threads COLMAP may use (0 = all)")
    # For side-by-side measurements, ~30 % slower (docs/decisions/colmap-reproducible.md).
    colmap_reproducible: bool = Field(
        False, description="COLMAP in one thread per process: the same result on every run")
    colmap_map_workers: int = Field(2, description="processes mapping windows side by side")
    ba_function_tolerance: float = Field(
        1e-6, description="bundle adjustments stop when an iteration gains less than this")
    # 100 stopped a stage 2 half way down its valley (docs/decisions/calib-stage2-iterations.md).
    calib_stage2_max_iterations: int = Field(
        1000, ge=1, description="iterations each of stage 2's bundle adjustments may take")
    # A way out of a stage 1 far off (docs/decisions/stage2-probe.md).
    calib_stage2_probe: float = Field(
        0.03, ge=0.0, lt=0.5, description="after stage 2, try fx, fy times 1 -/+ this; run stage 2 "
        "again from the one that fits better (0: never)")
    calib_stage2_probe_points: int = Field(
        1500, ge=100, description="points of the window the probe's deciding fits see")
    ba_max_refinements: int = Field(
        1, description="times COLMAP's mapper re-runs a bundle adjustment after dropping outliers")

    # Ego-motion: the frames near signs, in chained windows (docs/decisions/klt-ego-motion.md).
    sign_window_margin_frames: int = Field(15, description="frames added before/after a sign track")
    # More signs placed, faster (docs/decisions/ego-window-length.md).
    ego_max_frames_per_window: int = Field(
        120, description="journey frames one ego-motion window spans at most (then a chain)")
    ego_frame_step: int = Field(2, description="map every n-th frame near the signs")
    # More signs placed where a window could not start (docs/decisions/ego-more-init-pairs.md).
    ego_more_init_pairs: int = Field(
        3, description="initial pairs tried after the first before COLMAP's own choice")
    ego_window_overlap_frames: int = Field(
        16, description="frames consecutive windows of a stretch share (0: no chaining)")
    ego_bridge_gap_frames: int = Field(
        40, description="stretches near signs at most this many frames apart are joined")
    ego_front_end: Literal["klt", "sift"] = Field(
        "klt", description="how ego-motion finds correspondences between frames")
    # KLT loses frames metres apart (docs/decisions/ego-sift-spacing.md); cheaper ways there lost
    # signs (docs/decisions/ego-sift-cost.md).
    ego_sift_min_spacing_m: float = Field(
        1.7, description="SIFT instead of KLT where mapped frames lie farther apart, m (0: never)")
    klt_max_corners: int = Field(600, description="KLT corners kept per frame")
    klt_pair_overlap: int = Field(4, description="KLT: mapped frames a frame is paired with ahead")

    # GPS noise assumed by the joint alignment (1 sigma, metres).
    gps_sigma_m: float = 0.5
    gps_alt_sigma_m: float = 1.0

    # Alignment to GPS.
    # Straight lines between fixes cut curves' corners (docs/decisions/gps-smoothing.md).
    gps_smoothing: bool = Field(
        True, description="align to positions from a smoothing spline through the GPS fixes")
    # Interpolation across a dropout cuts a curve's corner (docs/decisions/gps-dropouts.md).
    gps_dropout_gap_factor: float = Field(
        1.5, description="frames in gaps over this many fix intervals neither align nor judge "
        "(0: use every frame)")
    # "full" measured better than the paper's "short" (docs/decisions/alignment-around-signs.md).
    alignment: Literal["short", "full", "local"] = "full"
    short_alignment_min_frames: int = 10
    local_alignment_weight: float = Field(
        1.0, description="local alignment: share of the correction around a sign applied")
    short_alignment_margin_frames: int = Field(
        15, description="short/local alignment: frames around a sign's track it takes in")
    alignment_joint: bool = Field(
        True, description="align windows that share frames jointly, not each on its own")
    # A broken window bends its neighbours (docs/decisions/alignment-unlink-broken.md).
    alignment_unlink_broken: bool = Field(
        True, description="a window over max_alignment_rms_gps_ratio is aligned on its own")
    # A broken window mended rather than discarded (docs/decisions/broken-window-mend.md).
    alignment_mend_broken: bool = Field(
        True, description="a window over max_alignment_rms_gps_ratio is mended where a run of "
        "bad fixes explains it")
    # An antenna offset nobody declared is estimated from the windows that turn
    # (docs/decisions/antenna-offset.md); applied only when it is this sure.
    antenna_offset_max_sigma_m: float = Field(
        0.2, description="an estimated GPS antenna offset is applied when its 1-sigma (m) is "
        "below this (0: never applied, still reported)")

    # Triangulation.
    min_track_frames: int = 3
    max_reprojection_rms_px: float = 4.0
    # More signs placed, none false (docs/decisions/min-inlier-share.md).
    min_inlier_share: float = Field(
        0.7, description="a poor track is placed again from its inliers when they are at least "
        "this share of it (1: never)")
    max_sign_std_m: float = 2.0
    min_ray_angle_deg: float = 1.0
    # Good windows lay <= 3.1x the GPS noise off (docs/decisions/broken-window-limit.md).
    max_alignment_rms_gps_ratio: float = Field(
        5.0, description="a window alignment rms above this many GPS sigmas: it broke")
    min_alignment_rms_reject_m: float = Field(
        1.0, description="...but never below this rms (m)")
    merge_fragments_within_m: float = Field(
        1.0, description="tracks of one class this close sharing no frame are one sign")
    # 95 % radii that hold 95 % of the signs (docs/decisions/sign-uncertainty.md).
    sign_georef_floor_m: float = Field(
        0.15, description="GPS error per axis no alignment averages out, m (stated accuracy "
        "raises it)")
    sign_georef_noise_gain: float = Field(
        1.0, description="gain on the averaged GPS noise in a sign's covariance")
    sign_georef_bias_quad_per_m: float = Field(
        0.40, description="plus this times the alignment's residual rms squared (1/m)")

    reuse_known_calibration: bool = Field(
        False, description="skip self-calibration when a calibration of this camera is known")
    check_known_calibration: bool = Field(
        True, description="a journey whose camera is calibrated maps its turn with that "
        "calibration held and uses it when the turn confirms it, instead of self-calibrating "
        "(cameras.check_on_turn)")
    camera_check_max_rel: float = Field(
        0.03, gt=0.0, description="the turn confirms the camera when its own estimate is this "
        "close: fx, fy relatively, cx, cy as a share of the image size (as the service's "
        "calibration_flag_rel)")

    # Self-calibration acceptance.
    min_turn_rotation_deg: float = Field(20.0, description="rotation a window needs to calibrate")
    max_calib_reprojection_px: float = 1.0


class BundleLimits(BaseModel):
    """Upper bounds on what one uploaded bundle may cost to validate and read (environment
    ``SIGNMAP_BUNDLE__<NAME>``). Each is checked before the work it bounds is spent: declared sizes
    before anything is unpacked, header sizes before a frame is decoded, row counts while the tables
    stream. The defaults hold a day of 4K dash-cam driving with a wide margin."""

    model_config = ConfigDict(frozen=True)

    max_uncompressed_bytes: int = Field(
        8 * 2**30, description="total bytes the bundle's entries may unpack to")
    # Frames are JPEG/PNG (already compressed) so a real bundle unpacks to about its own size; a
    # zip of padded or blank data unpacks to hundreds of times its size.
    max_unpack_ratio: float = Field(
        20.0, description="a bundle unpacking to more than max_unpack_ratio_floor_bytes may unpack "
        "to at most this many times its zipped size")
    max_unpack_ratio_floor_bytes: int = Field(
        64 * 2**20, description="bundles unpacking to at most this many bytes skip the ratio check")
    max_files: int = Field(200_000, description="entries in the zip")
    max_frames: int = Field(100_000, description="frames in one journey")
    # One entry is held in memory at a time (a frame to decode it): this bounds that memory.
    max_member_bytes: int = Field(
        96 * 2**20, description="bytes one entry (frame, gps.csv, detections.csv) may unpack to")
    # 4096 x 4096: 4K (8.3 MP) and 5K (14.7 MP) dash cams fit; a tiny PNG may declare gigapixels.
    max_frame_pixels: int = Field(
        16 * 2**20, description="pixels per frame (width x height), read from the image header")
    max_detections: int = Field(300_000, description="rows of detections.csv")
    max_boxes_per_frame: int = Field(200, description="detection boxes in one frame")
    max_gps_rows: int = Field(
        1_000_000, description="rows of gps.csv, track points of gps.gpx, lines of gps.nmea or "
        "fixes of a video's own GPS track")
    # A video journey (contract 1a): dash cams cut recordings into clips of 1-10 minutes; an hour
    # at 60 fps bounds the worker's decoding time (its memory holds a frame or two at any length).
    max_video_bytes: int = Field(4 * 2**30, description="bytes of the video file in a bundle")
    max_video_s: float = Field(3600.0, description="seconds of video in one journey")
    max_video_frames: int = Field(
        3600 * 60, description="frames of video in one journey (as the container declares)")
