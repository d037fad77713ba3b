"""The markdown of ``signmap bench fleet`` (``bench.corpus.fleet``): issue 66's per-journey and
per-camera bars, the joint calibration beside the consensus."""

from __future__ import annotations

import numpy as np

# Issue 66's bars.
ALONE_FOCAL_PCT, ALONE_DISTORTION_PX, WRONG_PCT = 1.0, 1.0, 3.0
CAMERA_FOCAL_PCT, CAMERA_PP_PX, CAMERA_DISTORTION_PX, CAMERA_MAX_FOCAL_PCT = 0.3, 2.0, 0.5, 1.0
AGAIN_WITHIN = 0.10  # processed again: recall and abs median within 10 % of the true camera's


def _fmt(v, digits: int = 2, sign: bool = True) -> str:
    if v is None or not np.isfinite(v):
        return "-"
    return f"{v:+.{digits}f}" if sign else f"{v:.{digits}f}"


def _share(flags: list[bool]) -> str:
    return f"{sum(flags)}/{len(flags)}" + (f" ({100 * sum(flags) / len(flags):.0f} %)"
                                           if flags else "")


def alone_rows(journeys: list[dict]) -> list[str]:
    turning = [j for j in journeys if j["turns"]]
    calibrated = [j for j in turning if j.get("errors")]
    within = [abs(j["errors"]["fx_pct"]) <= ALONE_FOCAL_PCT
              and abs(j["errors"]["fy_pct"]) <= ALONE_FOCAL_PCT
              and (j["errors"].get("distortion_px") or 0.0) <= ALONE_DISTORTION_PX
              for j in calibrated]
    wrong = [abs(j["errors"]["fx_pct"]) > WRONG_PCT for j in calibrated]
    fx = [abs(j["errors"]["fx_pct"]) for j in calibrated]
    return ["| journeys calibrated alone | value |", "| --- | --- |",
            f"| turning journeys calibrated | {_share([bool(j.get('errors')) for j in turning])} |",
            f"| fx, fy within {ALONE_FOCAL_PCT:g} % and distortion within "
            f"{ALONE_DISTORTION_PX:g} px (of turning journeys) | "
            f"{_share(within + [False] * (len(turning) - len(calibrated)))} |",
            f"| accepted more than {WRONG_PCT:g} % off | {sum(wrong)} of {len(calibrated)} |",
            f"| abs fx error median / p90 | {_fmt(np.median(fx) if fx else None, sign=False)} / "
            f"{_fmt(np.quantile(fx, 0.9) if fx else None, sign=False)} % |"]


def _final(history: list[dict]) -> list[dict]:
    last: dict[str, dict] = {}
    for row in history:
        last[row["camera_id"]] = row
    return list(last.values())


def _meets(errors: dict) -> tuple[bool, bool, bool]:
    return (abs(errors["fx_pct"]) <= CAMERA_FOCAL_PCT,
            max(abs(errors["cx_px"]), abs(errors["cy_px"])) <= CAMERA_PP_PX,
            (errors.get("distortion_px") or 0.0) <= CAMERA_DISTORTION_PX)


def camera_bar_rows(history: list[dict]) -> list[str]:
    final = _final(history)
    out = ["| after all of a camera's journeys | joint | consensus (before) |",
           "| --- | --- | --- |"]
    for k, label in enumerate((f"fx within {CAMERA_FOCAL_PCT:g} %",
                               f"principal point within {CAMERA_PP_PX:g} px",
                               f"distortion within {CAMERA_DISTORTION_PX:g} px")):
        out.append(f"| {label} | {_share([_meets(r['joint_errors'])[k] for r in final])} | "
                   f"{_share([_meets(r['consensus_errors'])[k] for r in final])} |")
    seen = [r["distortion_seen_px"] <= CAMERA_DISTORTION_PX for r in final
            if r.get("distortion_seen_px") is not None]
    if seen:
        out.append(f"| distortion within {CAMERA_DISTORTION_PX:g} px where its turns' features "
                   f"reach (not the bar) | {_share(seen)} | - |")
    fy_ok = [abs(r["joint_errors"]["fy_pct"]) <= CAMERA_FOCAL_PCT if r["fy_resolved"] else
             abs(r["joint"]["fy"] - r["true"]["fy"]) <= 2 * r["sigma"]["fy"] for r in final]
    out.append(f"| fy within {CAMERA_FOCAL_PCT:g} % where resolved, else within 2 sigma | "
               f"{_share(fy_ok)} | - |")
    for key in ("joint_errors", "consensus_errors"):
        worst = max((abs(r[key]["fx_pct"]) for r in final), default=float("nan"))
        out.append(f"| worst fx ({key.split('_')[0]}) | {_fmt(worst, sign=False)} % "
                   f"(bar {CAMERA_MAX_FOCAL_PCT:g} %) | |")
    return out


def _seen(row: dict) -> str:
    """The joint distortion's error within the reach of the windows' features (rows written
    before it was measured have none)."""
    if row.get("seen_px") is None:
        return "-"
    return (f"{_fmt(row['distortion_seen_px'], 2, sign=False)} "
            f"({100 * row['seen_px'] / row['corner_px']:.0f} %)")


def camera_table(history: list[dict], journeys: list[dict]) -> list[str]:
    """Each camera after all its journeys. Beside the distortion error over the whole image (the
    bar): the same within the reach of its windows' features (95th percentile distance from the
    principal point, as a share of the corner's), and the whole camera's error (focal length and
    principal point included)."""
    total: dict[str, int] = {}
    for j in journeys:
        total[j["camera_id"]] = total.get(j["camera_id"], 0) + 1
    out = ["| camera | journeys (calibrated) | left out | fx % | fy % (sigma, resolved) | cx, cy px "
           "| distortion px | where its turns reach: px (reach) | whole camera px | consensus fx % "
           "| consensus distortion px |",
           "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in _final(history):
        e, c = r["joint_errors"], r["consensus_errors"]
        fy_sigma_pct = 100 * r["sigma"]["fy"] / r["joint"]["fy"]
        out.append(f"| {r['camera_id']} | {total[r['camera_id']]} ({r['windows']}) | "
                   f"{len(r['left_out'])} | {_fmt(e['fx_pct'])} | {_fmt(e['fy_pct'])} "
                   f"({_fmt(fy_sigma_pct, sign=False)}, {'yes' if r['fy_resolved'] else 'no'}) | "
                   f"{_fmt(e['cx_px'], 1)}, {_fmt(e['cy_px'], 1)} | "
                   f"{_fmt(e.get('distortion_px'), 2, sign=False)} | "
                   f"{_seen(r)} | "
                   f"{_fmt(e.get('projection_px'), 2, sign=False)} | {_fmt(c['fx_pct'])} | "
                   f"{_fmt(c.get('distortion_px'), 2, sign=False)} |")
    return out


def history_rows(history: list[dict]) -> list[str]:
    """abs fx error by the number of windows fitted: how a camera improves as journeys come."""
    by_n: dict[int, list[dict]] = {}
    for r in history:
        by_n.setdefault(r["windows"], []).append(r)
    out = ["| windows | cameras | abs fx % median (joint / consensus) | worst (joint / consensus) |",
           "| --- | --- | --- | --- |"]
    for n in sorted(by_n):
        j = [abs(r["joint_errors"]["fx_pct"]) for r in by_n[n]]
        c = [abs(r["consensus_errors"]["fx_pct"]) for r in by_n[n]]
        out.append(f"| {n} | {len(j)} | {_fmt(np.median(j), sign=False)} / "
                   f"{_fmt(np.median(c), sign=False)} | {_fmt(max(j), sign=False)} / "
                   f"{_fmt(max(c), sign=False)} |")
    return out


def _fx(errors: dict | None) -> str:
    return f"{_fmt(errors['fx_pct'])} %" if errors else "-"


def second_journey_rows(seconds: list[dict]) -> list[str]:
    """Each camera's first journey and its second (with a turn) side by side: the second
    self-calibrating as a new camera's does, and checking the camera the first calibrated
    (``cameras.check_on_turn``); the time ratio is of the same run."""
    out = ["| camera | first journey: calibrate s (fx) | second, self-calibrating: s (fx) | "
           "second, checked: s | outcome | camera used fx | its turn's fx |",
           "| --- | --- | --- | --- | --- | --- | --- |"]
    ratios, confirmed = [], 0
    for row in seconds:
        first, own, checked = row["first"], row["self"], row["checked"]
        outcome = {"checked": "confirmed", "self": "not confirmed: self-calibrated",
                   "supplied": "unchecked"}.get(checked["source"], checked["error"] or "failed")
        confirmed += checked["source"] == "checked"
        if own.get("calibrate_s") and checked.get("calibrate_s"):
            ratios.append(checked["calibrate_s"] / own["calibrate_s"])
        out.append(f"| {row['camera_id']} | {_fmt(first.get('calibrate_s'), 1, False)} "
                   f"({_fx(first.get('errors'))}) | {_fmt(own.get('calibrate_s'), 1, False)} "
                   f"({_fx(own.get('errors'))}) | {_fmt(checked.get('calibrate_s'), 1, False)} | "
                   f"{outcome} | {_fx(checked['errors'])} | {_fx(checked['turn_errors'])} |")
    out += [f"\n{row['camera_id']}: {row['checked']['not_confirmed']}" for row in seconds
            if row["checked"].get("not_confirmed")]
    out += ["", f"Confirmed {confirmed} of {len(seconds)}; calibrate time checked / "
            f"self-calibrating, median "
            f"{_fmt(np.median(ratios) if ratios else None, 2, False)}, worst "
            f"{_fmt(max(ratios) if ratios else None, 2, False)} (per camera, same run)."]
    return out


def _placed(runs: list[dict]) -> tuple[int, int, int, float | None]:
    """(found, mappable, false, abs median m) over ``runs``' signs."""
    errors = [e for r in runs for e in r["abs_m"]]
    return (sum(r["found"] for r in runs), sum(r["mappable"] for r in runs),
            sum(r["false"] for r in runs), float(np.median(errors)) if errors else None)


def again_within(true: list[dict], again: list[dict]) -> bool:
    """Issue 66's bar: recall and abs median within ``AGAIN_WITHIN`` of the true camera's."""
    found_t, mappable, _, abs_t = _placed(true)
    found_a, _, _, abs_a = _placed(again)
    recall_ok = found_a >= (1.0 - AGAIN_WITHIN) * found_t
    abs_ok = abs_t is None or (abs_a is not None and abs_a <= (1.0 + AGAIN_WITHIN) * abs_t)
    return recall_ok and abs_ok


def again_rows(reprocessed: list[dict]) -> list[str]:
    """Each camera's journeys run with their true camera and processed again with the camera's
    joint calibration (checked on their turns, as the service does)."""
    if not reprocessed:
        return []
    out = ["| camera | journeys | true camera: found / mappable, false, abs median m | "
           "processed again: found / mappable, false, abs median m | again used | "
           f"within {100 * AGAIN_WITHIN:.0f} % |", "| --- | --- | --- | --- | --- | --- |"]
    for row in reprocessed + [{"camera_id": "all",
                               "true": [r for c in reprocessed for r in c["true"]],
                               "again": [r for c in reprocessed for r in c["again"]]}]:
        cells = []
        for way in ("true", "again"):
            found, mappable, false, abs_m = _placed(row[way])
            cells.append(f"{found} / {mappable}, {false}, {_fmt(abs_m, 3, sign=False)}")
        used = [r["source"] or "failed" for r in row["again"]]
        used_text = ", ".join(f"{used.count(u)} {u}" for u in sorted(set(used)))
        within = again_within(row["true"], row["again"])
        out.append(f"| {row['camera_id']} | {len(row['true'])} | {cells[0]} | {cells[1]} | "
                   f"{used_text} | {'yes' if within else 'no'} |")
    cameras = [again_within(c["true"], c["again"]) for c in reprocessed]
    out += ["", f"Cameras whose journeys, processed again, are within {100 * AGAIN_WITHIN:.0f} % "
            f"of their true-camera recall and abs median: {_share(cameras)}."]
    return out


def render_markdown(report: dict) -> str:
    parts = [f"# Fleet calibration: {report['corpus']} ({report['half'] or 'both halves'})", "",
             "Command: `signmap bench fleet --corpus ... "
             + (f"--half {report['half']}" if report["half"] else "") + "`", "",
             *alone_rows(report["journeys"]), "", *camera_bar_rows(report["history"]), "",
             *camera_table(report["history"], report["journeys"]), "",
             *history_rows(report["history"]), "",
             *second_journey_rows(report.get("second_journeys", [])), "",
             *again_rows(report.get("processed_again", []))]
    return "\n".join(parts).rstrip("\n") + "\n"
