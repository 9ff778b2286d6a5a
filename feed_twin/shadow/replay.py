"""Replay: the shadow twin run against a recorded bag as fast as possible, and what it writes.

`replay` reads the machine's command and measured streams from the bag (bagstreams), feeds them
to a `ShadowTwin` in their arrival order, one second of arrivals at a time (the fault policy
decides on each stream's own arrival order, so the result is the one the live twin would have
produced), and returns every paired sample, the health verdicts, the fault counts and the
metrics of the discrepancy workflow (feed_twin.analysis.compare.compute_metrics) on the twin's
samples. On a bag without message faults these equal `feed-twin simulate` on the same bag.

`write_outputs` writes, into the output directory:
- `comparison/`: a rosbag2 bag with every original topic (the same bytes, times and recorded
  QoS metadata, `offered_qos_profiles`) plus the
  twin's `<ns>/twin/state` (AxisState: the predicted state), `<ns>/twin/residual`
  (TwinResidual) and `<ns>/twin/health` (HealthStatus), where `<ns>` is the command topic's
  namespace; the twin's log times are the slot stamps shifted by the measured stream's median
  (log time - stamp), so they line up with the original topics in a viewer;
- `replay.rrd`: measured vs twin following error and effort, the residuals with their rolling
  RMS, and the health verdicts as a text log;
- `report.json` and `report.md`: metrics, fault counts, health summary.
"""

from __future__ import annotations

import json
import math
import posixpath
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from feed_twin.analysis.compare import Metrics, compute_metrics
from feed_twin.analysis.twin import ModelDoc, Twin
from feed_twin.io import msg_types
from feed_twin.io.bag import QosProfile
from feed_twin.io.measured import ColumnMap, MeasuredDataError
from feed_twin.nodeset.roles import node_role
from feed_twin.shadow.bagstreams import Stream, read_streams
from feed_twin.shadow.config import ShadowConfig
from feed_twin.shadow.health import LEVEL_NAMES, Verdict
from feed_twin.shadow.twin import ResidualBlock, ShadowTwin

CHUNK_S = 1.0  # [s] of arrivals fed between two process() calls
# what the live twin node offers on its topics (feed_twin.ros.dds.DATA_QOS), so that the
# comparison bag's twin topics read as a recording of the live twin would
TWIN_QOS = QosProfile(
    history="keep_last", depth=5000, reliability="reliable", durability="transient_local"
)
NS = 1_000_000_000


@dataclass(frozen=True, kw_only=True, eq=False)
class ReplayResult:
    samples: ResidualBlock
    verdicts: tuple[Verdict, ...]
    counts: dict[str, Any]
    metrics: Metrics
    effort_name: str | None
    effort_unit: str
    window_s: float  # [s] of the rolling RMS values
    streams: dict[str, Stream]


def replay(bag: str | Path, doc: ModelDoc, cmap: ColumnMap, config: ShadowConfig) -> ReplayResult:
    """Run the shadow twin of `doc` against the bag's streams (see the module docstring)."""
    streams = read_streams(bag, cmap)
    cmd, meas = streams["command"], streams["measured"]
    effort_name = next((n for n in meas.signals if n != "pos_meas_m"), None)
    twin = Twin.compile(doc)
    if effort_name is not None and effort_name != twin.effort_name:
        raise MeasuredDataError(
            f"{cmap.source}: the map gives the effort as {effort_name}, but {doc.source} "
            f"produces {twin.effort_name}"
        )
    shadow = ShadowTwin(
        twin,
        config,
        command_velocity="vel_cmd_m_s" in cmd.signals,
        travel_m=cmap.plausibility.travel_m,
        effort_sample=cmap.effort_sample,
        measured_effort=effort_name is not None,
    )
    start = min(int(cmd.log_time_ns[0]), int(meas.log_time_ns[0]))
    end = max(int(cmd.log_time_ns[-1]), int(meas.log_time_ns[-1]))
    step = round(CHUNK_S * NS)
    blocks: list[ResidualBlock] = []
    verdicts: list[Verdict] = []
    first = cmd if cmd.log_time_ns[0] <= meas.log_time_ns[0] else meas
    shadow.set_origin(float(first.stamp_s[0]))
    ic = im = 0
    for edge in range(start + step, end + step + 1, step):
        jc = int(np.searchsorted(cmd.log_time_ns, edge, side="left"))
        jm = int(np.searchsorted(meas.log_time_ns, edge, side="left"))
        shadow.push_commands(
            cmd.stamp_s[ic:jc],
            cmd.signals["pos_cmd_m"][ic:jc],
            cmd.signals["vel_cmd_m_s"][ic:jc] if shadow.command_velocity else None,
        )
        shadow.push_measured_many(
            meas.stamp_s[im:jm],
            meas.signals["pos_meas_m"][im:jm],
            meas.signals[effort_name][im:jm] if effort_name else None,
        )
        ic, im = jc, jm
        block = shadow.process()
        verdicts += shadow.new_verdicts
        if block is not None:
            blocks.append(block)
    block = shadow.process(final=True)
    verdicts += shadow.new_verdicts
    if block is not None:
        blocks.append(block)
    if not blocks:
        raise MeasuredDataError(f"{bag}: the twin produced no samples (no command or no measured)")
    samples = ResidualBlock.concat(blocks)
    ok = np.isfinite(samples.x_twin_m)
    has_effort = effort_name is not None and bool(np.isfinite(samples.effort_meas).any())
    metrics = compute_metrics(
        samples.x_meas_m[ok],
        samples.x_twin_m[ok],
        samples.effort_meas[ok] if has_effort else None,
        samples.effort_twin[ok] if has_effort else None,
        effort_unit=twin.effort_unit,
    )
    return ReplayResult(
        samples=samples,
        verdicts=tuple(verdicts),
        counts=shadow.counts(),
        metrics=metrics,
        effort_name=effort_name,
        effort_unit=twin.effort_unit,
        window_s=config.window_s,
        streams=streams,
    )


def twin_namespace(command_topic: str) -> str:
    parent = posixpath.dirname(command_topic)
    return posixpath.join(parent if parent != "/" else "", "twin") if parent else "/twin"


def _stamp(t_s: float) -> tuple[int, int]:
    ns = round(t_s * NS)
    return ns // NS, ns % NS


def write_comparison_bag(bag: str | Path, result: ReplayResult, out: Path, axis: str) -> Path:
    """The original topics plus the twin's (see the module docstring)."""
    from mcap.reader import make_reader

    from feed_twin.io.bag import BagWriter, info
    from feed_twin.io.cdr import FlatCodec

    ns = twin_namespace(result.streams["command"].topic)
    topics = {
        t.name: (node_role("twin").topic(ns, t.name), t.type_name)
        for t in node_role("twin").topics
        # (its packed outputs beside a LinuxCNC bridge are these topics' messages again)
        if t.direction == "publishes" and t.type_name != msg_types.RECORD_BATCH
    }
    meas = result.streams["measured"]
    offset_ns = int(np.median(meas.log_time_ns - np.round(meas.stamp_s * NS).astype(np.int64)))
    source = info(bag)
    path = out / "comparison"
    with BagWriter(path, flush_period_s=None) as writer:
        for t in source.topics:
            # the QoS the machine's publishers offered, as recorded (a bag from a tool that
            # stored none gets rosbag2's default)
            writer.add_topic(t.name, t.type_name, qos=t.offered_qos_profiles or (QosProfile(),))
        with open(source.mcap_path, "rb") as f:
            for _, channel, message in make_reader(f).iter_messages(log_time_order=True):
                writer.write(
                    channel.topic,
                    message.data,
                    log_time_ns=message.log_time,
                    publish_time_ns=message.publish_time,
                )
        for name, type_name in topics.values():
            writer.add_topic(name, type_name, qos=(TWIN_QOS,))
        s = result.samples
        state = FlatCodec(topics["state"][1])
        resid = FlatCodec(topics["residual"][1])
        is_current = result.effort_unit == "A"
        window = result.window_s
        for k in range(len(s)):
            sec, nsec = _stamp(float(s.t_s[k]))
            log = int(round(float(s.t_s[k]) * NS)) + offset_ns
            fe_twin = float(s.x_cmd_m[k] - s.x_twin_m[k])
            values = {
                "header.stamp.sec": sec,
                "header.stamp.nanosec": nsec,
                "axis": axis,
                "position_setpoint": float(s.x_cmd_m[k]),
                "table_position": float(s.x_twin_m[k]),
                "following_error": fe_twin,
            }
            if is_current:
                values["i_q"] = float(s.effort_twin[k])
            writer.write(topics["state"][0], state.encode_map(values), log_time_ns=log)
            writer.write(
                topics["residual"][0],
                resid.encode_map(
                    {
                        "header.stamp.sec": sec,
                        "header.stamp.nanosec": nsec,
                        "axis": axis,
                        "following_error_measured": float(s.x_cmd_m[k] - s.x_meas_m[k]),
                        "following_error_twin": fe_twin,
                        "following_error_deviation": float(s.fe_dev_m[k]),
                        "effort_measured": float(s.effort_meas[k]),
                        "effort_twin": float(s.effort_twin[k]),
                        "effort_deviation": float(s.effort_dev[k]),
                        "rms_window": window,
                        "following_error_deviation_rms": float(s.fe_dev_rms_m[k]),
                        "effort_deviation_rms": float(s.effort_dev_rms[k]),
                    }
                ),
                log_time_ns=log,
            )
        health = FlatCodec(topics["health"][1])
        for v in result.verdicts:
            writer.write(
                topics["health"][0],
                health.encode(health_values(health.names, v, axis)),
                log_time_ns=int(round(v.t_s * NS)) + offset_ns,
            )
    return path


def health_values(names: tuple[str, ...], v: Verdict, axis: str) -> list:
    """HealthStatus field values (FlatCodec order) of a verdict."""
    sec, nsec = _stamp(v.t_s)
    by_name = {
        "header.stamp.sec": sec,
        "header.stamp.nanosec": nsec,
        "header.frame_id": "",
        "axis": axis,
        "level": v.level,
        "effect": v.effect,
        "parameter": v.parameter,
        "unit": v.unit,
        "nominal_value": v.nominal_value,
        "estimated_value": v.estimated_value,
        "relative_change": v.relative_change,
        "message": v.message,
    }
    return [by_name[n] for n in names]


def write_rerun(result: ReplayResult, path: Path) -> Path:
    """Machine vs twin, residuals and health (feed_twin.shadow.dashboard) in an .rrd file."""
    from feed_twin.shadow.dashboard import ShadowDashboard

    dash = ShadowDashboard(effort_unit=result.effort_unit, rrd_path=path)
    dash.log_block(result.samples)
    for v in result.verdicts:
        dash.log_verdict(v)
    dash.close()
    return path


def report_dict(result: ReplayResult, *, bag: str, config: str) -> dict[str, Any]:
    levels = [v.level for v in result.verdicts]
    warnings = [v for v in result.verdicts if v.level != 0]
    s = result.samples
    return {
        "bag": bag,
        "config": config,
        "samples": len(s),
        "duration_s": float(s.t_s[-1] - s.t_s[0]) if len(s) else 0.0,
        "metrics": result.metrics.as_dict(),
        "effort_name": result.effort_name,
        "effort_unit": result.effort_unit,
        "faults": result.counts,
        "health": {
            "evaluations": len(levels),
            "levels": {LEVEL_NAMES[k]: levels.count(k) for k in LEVEL_NAMES},
            "first_warning": None if not warnings else asdict(warnings[0]),
            "last": None if not result.verdicts else asdict(result.verdicts[-1]),
        },
    }


def _fmt(value: float | None, scale: float = 1.0) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    return f"{value * scale:.4g}"


def report_markdown(d: dict[str, Any]) -> str:
    m = d["metrics"]
    h = d["health"]
    lines = [
        "# Replay report",
        "",
        f"- bag: `{d['bag']}`",
        f"- model: `{d['config']}`",
        f"- {d['samples']} samples, {d['duration_s']:.3f} s",
        "",
        "| FE dev. RMS [um] | FE dev. max [um] | position rel. error [%] | "
        "effort rel. error [%] | effort residual RMS |",
        "|---|---|---|---|---|",
        f"| {_fmt(m['fe_dev_rms_m'], 1e6)} | {_fmt(m['fe_dev_max_m'], 1e6)} | "
        f"{_fmt(m['pos_rel_err_pct'])} | {_fmt(m['effort_rel_err_pct'])} | "
        f"{_fmt(m['effort_rms'])} {d['effort_unit']} |",
        "",
        "## Message faults",
        "",
        "| stream | received | reordered | duplicated | late | off grid | rejected | missing |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for kind in ("command", "measured"):
        c = d["faults"][kind]
        lines.append(
            f"| {kind} | {c['received']} | {c['reordered']} | {c['duplicated']} | {c['late']} | "
            f"{c['off_grid']} | {c['rejected']} | {c['missing']} |"
        )
    lines += [
        "",
        f"Twin restarts after a divergence: {d['faults']['twin_restarts']}",
        "",
        "## Health",
        "",
        f"{h['evaluations']} evaluations: " + ", ".join(f"{k} {n}" for k, n in h["levels"].items()),
    ]
    if h["first_warning"] is not None:
        w = h["first_warning"]
        lines.append(f"First warning at t = {w['t_s']:.3f} s: {w['message']}")
    if h["last"] is not None:
        last = h["last"]
        lines.append(f"Last verdict ({LEVEL_NAMES[last['level']]}): {last['message']}")
    return "\n".join(lines) + "\n"


def write_report(result: ReplayResult, out: Path, *, bag: str, config: str) -> list[Path]:
    d = report_dict(result, bag=bag, config=config)
    out.mkdir(parents=True, exist_ok=True)
    json_path = out / "report.json"
    json_path.write_text(json.dumps(d, indent=2, default=_json_default, allow_nan=True) + "\n")
    md_path = out / "report.md"
    md_path.write_text(report_markdown(d))
    return [json_path, md_path]


def _json_default(value: Any) -> Any:
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot write {type(value).__name__} to JSON")
