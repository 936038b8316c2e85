"""The validation report a person reads: REPORT.md (verdict first, then the why), figures, validation.json.

REPORT.md is rendered from the same typed records (results.ValidationRun)
whose `as_dict()` validation.json holds, so the two never disagree; figures
live in one folder per bag next to it.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from roi_node import __version__
from roi_node.engine.errors import BagError
from roi_node.engine.metadata import METADATA_SCHEMA
from roi_node.engine.stamps import NS_PER_S
from roi_node.quality.figures import figures
from roi_node.quality.figures.contact_sheet import contact_row, contact_sheet, unresize_global
from roi_node.quality.gates import GateSet, format_value
from roi_node.quality.roibag import RoiBag
from roi_node.wire import topics

if TYPE_CHECKING:
    from roi_node.quality.drift import ArmDrift
    from roi_node.quality.results import BagScan, BagValidation, ValidationRun
    from roi_node.quality.rollout import RolloutPart
    from roi_node.quality.samples import Sample
    from roi_node.quality.validation_records import CalibrationPart

REPORT_NAME = "REPORT.md"
JSON_NAME = "validation.json"
FIGURE_TITLES = {
    "contact_sheet": "Contact sheet: sampled frames with the crop boxes, ROI crops beside them",
    "trajectory": "ROI centre trajectory over the image",
    "timeseries": "In-frame ratio, padding ratio and confidence over time",
    "jitter": "Centre step per frame vs motion-aware jitter",
    "sync": "Sync residual",
    "visibility": "Gripper visible fraction over time and its distribution (rigs with visibility enabled)",
}
RESULT_MARK = {"pass": "✅ pass", "fail": "❌ FAIL", "no_data": "– no data"}


def prepare_report_dir(path: Path) -> None:
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise BagError(f"{path}: cannot create the report folder ({exc.strerror or exc})") from exc


def _write(path: Path, write: Any) -> None:
    try:
        write()
    except OSError as exc:
        raise BagError(f"{path}: cannot write the report ({exc.strerror or exc})") from exc


def thresholds(gates: GateSet) -> dict[str, list[tuple[str, float]]]:
    out: dict[str, list[tuple[str, float]]] = {}
    for gate in gates.gates:
        out.setdefault(gate.metric, []).append((gate.op, gate.threshold))
    return out


def input_image_topic(scan: BagScan) -> str | None:
    """The recorded camera topic, when the ROI bag carries its inputs (replay --include-inputs); for one camera of
    several, its default topic /<camera>/image_raw."""
    names = [t.name for t in scan.topics.values() if t.msgtype == topics.IMAGE_TYPE]
    candidates = sorted(n for n in names if not n.startswith(topics.BAG_OUTPUT_PREFIX))
    if scan.camera is not None:
        own = topics.absolute(f"{scan.camera}/{topics.IMAGE}")
        return own if own in candidates else None
    return candidates[0] if candidates else None


def _sample_images(scan: BagScan) -> list[tuple[Sample, np.ndarray, list[np.ndarray]]]:
    """(sample, frame, ROI crops) for every sample whose frame the bag holds: the recorded
    full frame when the bag carries its inputs, else the global view with its letterbox removed."""
    source = input_image_topic(scan)
    out = []
    with RoiBag(scan.path, scan.camera) as bag:
        for sample in scan.samples:
            record = sample.record
            stamp = record.stamp_ns
            frame = bag.image(source, sample.log_ns, stamp) if source is not None else None
            if frame is None:
                view = bag.image(bag.global_topic, sample.log_ns, stamp)
                if view is None:
                    continue
                frame = unresize_global(view, record.image_size, record.lineage.resize_policy)
            rois = []
            for arm in record.arms:
                roi = bag.image(bag.roi_image_topic(arm.arm_id), sample.log_ns, stamp)
                rois.append(roi if roi is not None else np.zeros((256, 256, 3), np.uint8))
            out.append((sample, frame, rois))
    return out


def write_bag_figures(scan: BagScan, validation: BagValidation, gates: GateSet, report_dir: Path) -> dict[str, str]:
    """PNG figures for one bag under report_dir/<name>/; returns figure -> path relative to report_dir."""
    folder = report_dir / validation.name
    prepare_report_dir(folder)
    series = scan.summary.series
    marks = thresholds(gates)
    sampled = _sample_images(scan)
    sizes = scan.summary.details["identity"]["image_sizes"]
    image_size = (int(sizes[0][0]), int(sizes[0][1]))
    images: dict[str, np.ndarray] = {}
    if sampled:
        rows = [
            contact_row(frame, sample.record, rois, f"frame_index {sample.record.frame_index}: {sample.reason}")
            for sample, frame, rois in sampled
        ]
        images["contact_sheet"] = contact_sheet(rows)
    background = sampled[0][1] if sampled else None
    images["trajectory"] = figures.trajectory(series, image_size, background)
    images["timeseries"] = figures.timeseries(series, marks)
    images["jitter"] = figures.jitter(series, marks)
    images["sync"] = figures.sync(series, marks)
    if any(arm.visible is not None and np.isfinite(arm.visible).any() for arm in series.arms.values()):
        images["visibility"] = figures.visibility(series, marks)
    out = {}
    for name, rgb in images.items():
        path = folder / f"{name}.png"
        _write(path, lambda p=path, img=rgb: figures.write_png(p, img))
        out[name] = path.relative_to(report_dir).as_posix()
    return out


def write_report(run: ValidationRun, report_dir: Path) -> None:
    doc = run.as_dict()
    _write(report_dir / JSON_NAME, lambda: (report_dir / JSON_NAME).write_text(json.dumps(doc, indent=2, allow_nan=False) + "\n"))
    _write(report_dir / REPORT_NAME, lambda: (report_dir / REPORT_NAME).write_text(render_markdown(run)))


# ---- Markdown -------------------------------------------------------------------------------


def _v(value: Any) -> str:
    """A table cell: numbers compact, and no `|` that would split the cell."""
    text = format_value(value) if value is None or isinstance(value, int | float) else str(value)
    return text.replace("|", "\\|")


def _table(header: Sequence[str], rows: Sequence[Sequence[Any]]) -> list[str]:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(_v(c) for c in row) + " |" for row in rows]
    return [*lines, ""]


def _duration(bag: BagValidation) -> str:
    return f"{bag.result.bag_metrics['duration_s']:.2f} s"


def render_markdown(run: ValidationRun) -> str:
    bags = run.bags
    n_failed = sum(1 for b in bags if b.failed)
    verdict = "PASS" if run.passed else "FAIL"
    gates = run.gates
    lines = [
        "# ROI bag validation",
        "",
        f"**Result: {verdict}** — {len(bags) - n_failed} of {len(bags)} bag(s) pass every gate.",
        "",
        f"roi_node {__version__} · metadata schema `{METADATA_SCHEMA}` · "
        f"gates `{gates.path}` (`{gates.sha256[:23]}`)" + (f" · baseline `{run.baseline}`" if run.baseline is not None else ""),
        "",
    ]
    rows = []
    for bag in bags:
        failed = ", ".join(f"{g.gate} ({g.arm})" for g in bag.failed) or "—"
        rows.append([f"[{bag.name}](#{bag.name.lower()})", bag.result.frames, _duration(bag), ", ".join(bag.result.arms),
                     RESULT_MARK["fail" if bag.failed else "pass"], failed])
    lines += _table(["bag", "frames", "duration", "arms", "result", "failed gates"], rows)
    for bag in bags:
        lines += _bag_section(bag)
    return "\n".join(lines)


def _bag_section(bag: BagValidation) -> list[str]:
    details, metrics = bag.result.details, bag.result.bag_metrics
    ident = details["identity"]
    sizes = ", ".join(f"{w}×{h}" for w, h in ident["image_sizes"])
    first, last = details["frame_index_range"]
    lines = [
        "---",
        f"## {bag.name}",
        "",
        f"`{bag.result.path}` · {metrics['frames']} frames · {_duration(bag)} · frame_index {first}–{last} · camera "
        f"{', '.join(ident['camera_ids'])} · robot {', '.join(ident['robot_ids'])} · image {sizes} · "
        f"{len(details['lineage'])} lineage tuple(s) · writer status: {details['writer_status'] or 'not recorded'}",
        "",
        "### Gates",
        "",
    ]
    order = {"fail": 0, "no_data": 1, "pass": 2}
    gate_rows = [
        [RESULT_MARK[g.status], g.gate, g.arm, g.value, g.threshold_text()]
        for g in sorted(bag.gates, key=lambda g: order[g.status])
    ]
    lines += _table(["result", "gate", "arm", "value", "threshold"], gate_rows) if gate_rows else ["No gates configured.", ""]
    if bag.figures:
        lines += ["### Figures", ""]
        for name, path in bag.figures.items():
            lines += [f"**{FIGURE_TITLES[name]}**", "", f"![{name}]({path})", ""]
    lines += _arm_section(bag)
    lines += _timing_section(bag)
    lines += _drift_section(bag)
    lines += _calibration_section(bag.result.calibration)
    lines += _rollout_section(bag.result.rollout)
    lines += _lineage_section(details["lineage"])
    lines += _governance_section(bag)
    return lines


ARM_ROWS = (
    ("projection valid ratio", ("projection_valid_ratio",)),
    ("frames present / valid / invalid", ("present_frames", "valid_frames", "invalid_frames")),
    ("in-frame ratio mean / p05 / min", ("in_frame_ratio_mean", "in_frame_ratio_p05", "in_frame_ratio_min")),
    ("frames fully / partially out of frame", ("fully_out_of_frame_frames", "partially_out_of_frame_frames")),
    ("longest run of frames showing nothing", ("out_of_frame_longest_run",)),
    ("padding ratio p50 / p95 / max", ("padding_ratio_p50", "padding_ratio_p95", "padding_ratio_max")),
    ("confidence p05 / p50 / mean", ("confidence_p05", "confidence_p50", "confidence_mean")),
    ("window side px p05 / p50 / p95", ("scale_px_p05", "scale_px_p50", "scale_px_p95")),
    ("centre step px p50 / p95 / max", ("center_step_px_p50", "center_step_px_p95", "center_step_px_max")),
    ("motion-aware centre jitter px p50 / p95 / max", ("center_jitter_px_p50", "center_jitter_px_p95", "center_jitter_px_max")),
    ("scale step p50 / p95 / max", ("scale_step_p50", "scale_step_p95", "scale_step_max")),
    ("motion-aware scale jitter p50 / p95 / max", ("scale_jitter_p50", "scale_jitter_p95", "scale_jitter_max")),
    ("flagged frames / ratio", ("flagged_frames", "flagged_ratio")),
)


def _arm_section(bag: BagValidation) -> list[str]:
    arms = bag.result.arms
    rows = [[label, *(" / ".join(_v(arms[a].metrics[k]) for k in keys) for a in arms)] for label, keys in ARM_ROWS]
    return ["### Per-arm statistics", "", *_table(["metric", *arms], rows)]


INDEX_KEYS = ("frame_index_gaps", "frames_missing", "frame_index_disorder")


def _timing_section(bag: BagValidation) -> list[str]:
    m, sync = bag.result.bag_metrics, bag.result.details["sync"]
    status = ", ".join(f"{k} {v}" for k, v in sync["status"].items())
    rows = [
        ["sync residual ms p50 / p95 / max", " / ".join(_v(m[f"sync_residual_ms_{s}"]) for s in ("p50", "p95", "max"))],
        ["sync status", status],
        ["sync policy", ", ".join(f"{k} ({v})" for k, v in sync["policies"].items())],
        ["frames without a residual", sync["null_residual_frames"]],
        ["median frame period ms", m["median_period_ms"]],
        ["stamp gaps (longest, in periods)", f"{m['stamp_gaps']} ({_v(m['stamp_gap_max_periods'])})"],
        ["stamps out of order", m["stamp_disorder"]],
        ["frame_index gaps / frames missing / out of order", " / ".join(str(m[k]) for k in INDEX_KEYS)],
    ]
    return ["### Timing", "", *_table(["measure", "value"], rows)]


def _drift_rows(arms: Mapping[str, ArmDrift]) -> list[list[Any]]:
    rows = []
    for arm_id, d in arms.items():
        offset = d.center_offset_px
        shift = None if offset is None else float(np.hypot(*offset))
        rows.append([arm_id, d.mode, d.frames, "n/a" if offset is None else f"({offset[0]:.3f}, {offset[1]:.3f})", shift,
                     d.scale_ratio, d.in_frame_delta, d.padding_delta])
    return rows


def _calibration_section(check: CalibrationPart | None) -> list[str]:
    """check-calibration's findings, when validate ran it (--config, on a bag with its inputs)."""
    if check is None:
        return []
    if check.delay_ms is None:  # not measured: the reason says why
        delay = "Camera delay not measured"
    else:
        low, high = check.delay_ci_ms or (None, None)
        delay = f"Camera delay {check.delay_ms:g} ms (95% interval {low:g} .. {high:g}, confidence {check.delay_confidence:g})"
    reason = check.cannot_tell or check.delay_cannot_tell
    cannot = "" if reason is None else f" (cannot tell: {reason.reason}: {reason.detail})"
    lines = [
        "### Calibration from the images",
        "",
        f"{delay}; configured {check.configured_delay_ms:g} ms: {check.delay_verdict}"
        f"{cannot}. Verdict: {check.verdict}.",
        "",
    ]
    rows = [[arm, _list_or_none(a.offset_px), _list_or_none(a.spread_px), a.frames, a.verdict] for arm, a in check.arms.items()]
    lines += _table(["arm", "reprojection offset px (dx, dy)", "per-frame spread px", "frames", "verdict"], rows)
    lines += [f"- hint: {hint}" for hint in check.hints] + ([""] if check.hints else [])
    return lines


def _list_or_none(pair: tuple[float, float] | None) -> list[float] | None:
    """A pair as the table always showed it: the JSON list's text, [dx, dy]."""
    return None if pair is None else list(pair)


def _rollout_section(rollout: RolloutPart | None) -> list[str]:
    """A recorded rollout's policy-driven spans, and per arm the jitter and excursions there."""
    if rollout is None:
        return []
    lines = [
        "### Rollout",
        "",
        f"{rollout.commands} commands on `{rollout.command_topic}` (median period {_v(rollout.command_period_ms)} ms); "
        f"the policy drove {rollout.policy_driven_frames} frames ({_v(rollout.policy_driven_ratio)} of the bag) "
        f"in {len(rollout.spans)} span(s):",
        "",
    ]
    lines += _table(["span start ns", "end ns", "duration s", "commands", "frames"],
                    [[s.start_ns, s.end_ns, (s.end_ns - s.start_ns) / NS_PER_S, s.commands, s.frames] for s in rollout.spans])
    keys = ("rollout_jitter_rms", "rollout_jitter_px_rms", "rollout_excursions", "rollout_recovery_s_max", "rollout_unrecovered_excursions")
    rows = [[arm, *(metrics[k] for k in keys)] for arm, metrics in rollout.arm_metrics.items()]
    lines += _table(["arm", "jitter RMS / ROI side", "jitter RMS px", "excursions", "longest recovery s", "unrecovered"], rows)
    excursions = [[arm, e.left_ns, e.back_ns, e.recovery_s, e.min_in_frame, "yes" if e.policy_driven else "no"]
                  for arm in rollout.arm_metrics for e in rollout.arm_excursions(arm)]
    if excursions:
        lines += _table(["arm", "left frame ns", "back ns", "recovery s", "lowest in-frame", "policy-driven"], excursions)
    return lines


def _drift_section(bag: BagValidation) -> list[str]:
    header = ["arm", "mode", "frames", "centre offset (du, dv) px", "shift px", "scale ratio", "in-frame Δ", "padding Δ"]
    lines = ["### Drift", ""]
    base = bag.result.drift.baseline
    if base is not None:
        same = "same lineage" if base.same_lineage else "different lineage"
        lines += [f"Against baseline `{base.path}` ({base.mode}, {base.matched_frames} frames matched by stamp, {same}):", ""]
        lines += _table(header, _drift_rows(base.arms))
    window = bag.result.drift.window
    fraction = f"{window.fraction:.3g}"
    if window.arms:
        lines += [f"Last {fraction} of the bag against its first {fraction} (task motion moves these too):", ""]
        lines += _table(header, _drift_rows(window.arms))
    else:
        lines += ["The bag is too short to compare its first and last windows.", ""]
    return lines


def _lineage_section(segments: Sequence[Mapping[str, Any]]) -> list[str]:
    keys = ("intrinsics_ver", "extrinsics_ver", "fk_ver", "roi_generator_ver", "crop_offset_ver", "resize_policy", "padding_mode")
    rows = [[s["first_frame_index"], s["frames"], *(f"`{s['tuple'][k]}`" for k in keys)] for s in segments]
    note = "One lineage tuple for the whole bag." if len(segments) == 1 else f"**The lineage changes {len(segments) - 1} time(s).**"
    return ["### Lineage", "", note, "", *_table(["from frame_index", "frames", *keys], rows)]


def _governance_section(bag: BagValidation) -> list[str]:
    gov, teleop = bag.result.details["governance"], bag.result.details["teleop"]
    arms = list(bag.result.arms)
    flags = sorted({f for per_arm in gov["flags"].values() for f in per_arm})
    modes = f"Padding mode: {', '.join(gov['padding_modes'])} · resize policy: {', '.join(gov['resize_policies'])}"
    lines = ["### Governance", "", modes, ""]
    interp = [[a, ", ".join(f"{k} {v}" for k, v in gov["interpolation"][a].items())] for a in arms]
    lines += _table(["arm", "interpolation (frames)"], interp)
    if flags:
        lines += ["Quality flags (frames per arm):", ""]
        lines += _table(["flag", *arms], [[f, *(gov["flags"][a].get(f, 0) for a in arms)] for f in flags])
    else:
        lines += ["No quality flags.", ""]
    rows = [[name, t["present_frames"], t["p50"], t["p95"], t["max"]] for name, t in teleop.items()]
    lines += ["Teleoperation context (L_t, f_t, r_t):", "", *_table(["field", "frames present", "p50", "p95", "max"], rows)]
    custom = bag.result.custom_data
    if custom:
        lines += _table(["bag custom data", "value"], [[k, f"`{v}`"] for k, v in custom.items()])
    return lines
