"""What is in a dataset: totals and a provenance breakdown (for ``surrol-data info DIR`` and the dataset card).

Proficiency means follow :func:`surrol_data.datasets.metrics.summarize`: steps to success and path
length are averaged over the *successful* episodes of a group (an unsuccessful episode has no steps to
success, and its path is not comparable); jaw closures over all episodes.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from surrol_data.datasets.interventions import episode_interventions, operator_interventions
from surrol_data.datasets.reader import DatasetError, DatasetReader
from surrol_data.datasets.schema import SIDECAR_PATH, camera_renderer_of, camera_version_of

GROUP_BY = ("source", "device", "skill", "operator_id")


def _mean(values) -> float:
    values = [float(v) for v in values if v is not None and np.isfinite(v)]
    return float(np.mean(values)) if values else float("nan")


def _group_stats(rows) -> dict:
    ok = rows[rows["success"]] if len(rows) else rows
    return {
        "episodes": int(len(rows)),
        "frames": int(rows["length"].sum()),
        "success_rate": float(rows["success"].mean()) if len(rows) else float("nan"),
        "mean_steps_to_success": _mean(ok["steps_to_success"]),
        "mean_path_length_cm": _mean(ok["path_length_cm"]),
        "mean_jaw_closures": _mean(rows["jaw_closures"]),
    }


def read_sidecar(root: str | Path) -> dict:
    """``meta/surrol_data.json`` (dataset-level facts written by the recorder), ``{}`` if absent or broken."""
    path = Path(root) / SIDECAR_PATH
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return {}


def summarize(root: str | Path, reader: DatasetReader | None = None) -> dict:
    """Totals, features and a per-(source, device, skill, operator_id) breakdown of a dataset.

    Keys: root, codebase_version, robot_type, fps, episodes, frames, duration_s (frames / fps), tasks,
    features (name -> {dtype, shape}), sidecar (meta/surrol_data.json), has_provenance, overall (the
    group stats of all episodes) and groups (list of dicts: the GROUP_BY keys + episodes, frames,
    success_rate, mean_steps_to_success, mean_path_length_cm, mean_jaw_closures); interventions: a dataset of
    intervention sessions, per GROUP_BY group of operator the takeovers (see
    :func:`surrol_data.datasets.interventions.operator_interventions`), else [].
    """
    reader = reader or DatasetReader(root)
    info = reader.info
    eps = reader.episodes
    tasks = sorted(set(eps["task"])) if "task" in eps.columns else []
    needed = {*GROUP_BY, "success", "steps_to_success", "path_length_cm", "jaw_closures"}
    has_provenance = needed <= set(eps.columns)
    summary = {
        "root": str(Path(root)),
        "codebase_version": info.get("codebase_version", ""),
        "robot_type": info.get("robot_type") or "",
        "fps": int(info["fps"]),
        "episodes": int(len(eps)),
        "frames": int(eps["length"].sum()),
        "duration_s": float(eps["length"].sum()) / int(info["fps"]),
        "tasks": tasks,
        "features": {k: {"dtype": v["dtype"], "shape": list(v["shape"])} for k, v in info["features"].items()},
        "sidecar": read_sidecar(root),
        "has_provenance": has_provenance,
        "overall": _group_stats(eps) if has_provenance else {"episodes": int(len(eps)),
                                                             "frames": int(eps["length"].sum())},
        "groups": [],
        "interventions": [],
    }
    if has_provenance and len(eps):
        for key, rows in eps.groupby(list(GROUP_BY), sort=True):
            summary["groups"].append({**dict(zip(GROUP_BY, key, strict=True)), **_group_stats(rows)})
        counts = episode_interventions(reader)
        if counts is not None:
            summary["interventions"] = operator_interventions(eps.merge(counts, on="episode_index"), list(GROUP_BY))
    return summary


SKILL_GROUP_BY = ("source", "skill")


def _smoothness(reader: DatasetReader, episodes: list[int]) -> list[float]:
    """LDLJ of each episode, as :func:`~surrol_data.datasets.metrics.trajectory_proficiency` (and so ``assess``)
    reports it: of the device's recorded trace where the episode has one, else of the tip path up to success — from
    the three frame columns it needs, each data file read once (a Trajectory and every metric per episode cost
    ~10 ms an episode)."""
    from surrol_data.datasets.metrics import (CONTROL_PERIOD_S, log_dimensionless_jerk, recorded_device_trace,
                                              smoothness_path, steps_to_success)
    from surrol_data.datasets.reader import column_to_numpy

    if not episodes:
        return []
    tip, next_tip = "complementary_info.tip_position", "complementary_info.next_tip_position"
    table = reader._read_episodes(episodes, [tip, next_tip, "next.success"])
    n_arms = int(np.prod(reader.features[tip]["shape"])) // 3
    ep_col = column_to_numpy(table.column("episode_index"))
    tips = column_to_numpy(table.column(tip)).reshape(table.num_rows, n_arms, 3)
    next_tips = column_to_numpy(table.column(next_tip)).reshape(table.num_rows, n_arms, 3)
    success = column_to_numpy(table.column("next.success")).reshape(-1).astype(bool)
    firsts, starts, counts = np.unique(ep_col, return_index=True, return_counts=True)
    where = {int(e): (int(s), int(n)) for e, s, n in zip(firsts, starts, counts, strict=True)}
    out = []
    lengths = dict(zip(reader.episodes["episode_index"].astype(int), reader.episodes["length"].astype(int),
                       strict=True))
    for ep in episodes:
        start, n = where.get(int(ep), (0, 0))
        if n != lengths.get(int(ep), n):
            # the metadata checks do not read frames: frames relabelled or lost are found here, where they are read
            raise DatasetError(f"{reader.root}: the data files hold {n} frames of episode {ep}, its metadata says "
                               f"{lengths[int(ep)]}: the frames are damaged. Run `surrol-data validate {reader.root}` "
                               f"for the full check, `surrol-data repair {reader.root}` to keep its intact episodes")
        path = np.concatenate([tips[start:start + n], next_tips[start + n - 1:start + n]]).astype(np.float64)
        k = steps_to_success(success[start:start + n])
        smooth, dt, _ = smoothness_path(path[: k + 1] if k > 0 else path, CONTROL_PERIOD_S,
                                        recorded_device_trace(reader.root, ep))
        out.append(log_dimensionless_jerk(smooth, dt))
    return out


def skill_breakdown(root: str | Path, reader: DatasetReader | None = None) -> list[dict]:
    """Proficiency per (source, skill): how demos of experts, novices and scripts differ.

    Per group: episodes, success_rate, and over the *successful* episodes the mean and std of steps to
    success and path length (cm) and the mean log dimensionless jerk (LDLJ, higher = smoother; computed
    from the recorded tip path up to success, so the episode data is read); over all episodes the mean
    clutch uses and ``regrasp_rate``, the fraction of episodes with more than one jaw closure (a grasp
    that was retried). Empty when the dataset has no provenance.
    """
    reader = reader or DatasetReader(root)
    eps = reader.episodes
    if not {*SKILL_GROUP_BY, "success", "steps_to_success", "path_length_cm", "jaw_closures"} <= set(eps.columns):
        return []
    # every successful episode's LDLJ in one pass over the data files (one pass per group read every file again)
    successful = [int(e) for e in eps.loc[eps["success"].astype(bool), "episode_index"]]
    ldlj_of = dict(zip(successful, _smoothness(reader, successful), strict=True))
    groups = []
    for key, rows in eps.groupby(list(SKILL_GROUP_BY), sort=True):
        ok = rows[rows["success"]]
        ldlj = [ldlj_of[int(e)] for e in ok["episode_index"]]

        def std(values):
            values = [float(v) for v in values if np.isfinite(v)]
            return float(np.std(values)) if len(values) > 1 else float("nan")

        groups.append({
            **dict(zip(SKILL_GROUP_BY, key, strict=True)),
            "episodes": int(len(rows)),
            "success_rate": float(rows["success"].mean()),
            "mean_steps_to_success": _mean(ok["steps_to_success"]),
            "std_steps_to_success": std(ok["steps_to_success"]),
            "mean_path_length_cm": _mean(ok["path_length_cm"]),
            "std_path_length_cm": std(ok["path_length_cm"]),
            "mean_ldlj": _mean(ldlj),
            "mean_clutch_uses": _mean(rows["clutch_uses"]) if "clutch_uses" in rows else float("nan"),
            "regrasp_rate": float((rows["jaw_closures"] > 1).mean()),
        })
    return groups


def _fmt(value: float, digits: int = 1) -> str:
    return "–" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def info_facts(root: str | Path) -> dict:
    """Everything :func:`render_info` shows: ``{"summary": summarize(root), "by_skill": skill_breakdown(root)}``,
    as plain JSON values (what :mod:`surrol_data.datasets.info_cache` remembers)."""
    reader = DatasetReader(root)   # the episodes table read once for every part below
    summary = summarize(root, reader)
    by_skill = skill_breakdown(root, reader) if summary["has_provenance"] else []
    return {"summary": summary, "by_skill": by_skill}


CHECKED = {
    "metadata": "metadata and seals (info.json, every parquet footer, provenance and its seals, counts); not the "
                "frames: run `surrol-data validate` for those",
    "full": "everything: `surrol-data validate` passed on these very bytes",
}


def render_info(root: str | Path, label: str | Path | None = None, facts: dict | None = None):
    """A rich renderable (tables) of :func:`summarize`; print it with ``rich.console.Console().print``.
    ``facts``: :func:`info_facts` of ``root`` when the caller has them already (remembered by content digest)."""
    from rich import box
    from rich.console import Group
    from rich.table import Table

    facts = facts if facts is not None else info_facts(root)
    s = dict(facts["summary"], root=str(Path(root)))
    if label is not None:  # the dataset the user named, when ``root`` is the repaired view of a read-only one
        s["root"] = str(label)
    totals = Table(title=f"Dataset {s['root']}", show_header=False)
    totals.add_column("", style="bold")
    totals.add_column("")
    side = s["sidecar"]
    for label, value in (
        ("format", f"LeRobot {s['codebase_version']}" + (f", surrol_data schema {side['schema_version']}"
                                                          if "schema_version" in side else "")),
        ("task", ", ".join(s["tasks"]) or side.get("task", "–")),
        ("env id", side.get("env_id", "–")),
        ("robot", s["robot_type"] or "–"),
        ("episodes", str(s["episodes"])),
        ("frames", f"{s['frames']} ({s['duration_s']:.1f} s at {s['fps']} fps)"),
        *((("camera version", str(v)),) if (v := camera_version_of(side, s["features"])) is not None else ()),
        *((("camera renderer", r),) if (r := camera_renderer_of(side, s["features"])) is not None else ()),
    ):
        totals.add_row(label, value)
    checked = facts.get("checked")
    if checked is not None:   # what the numbers below rest on (see surrol_data.datasets.info_cache.checked_info)
        totals.add_row("checked", CHECKED[checked])
    signer = side.get("signature", {}).get("public_key") if isinstance(side.get("signature"), dict) else None
    if signer:
        totals.add_row("signed by", f"Ed25519 key {signer[:16]}… (not verified here: `surrol-data validate "
                                    "--trust KEY` checks it)")
    if s["has_provenance"]:
        o = s["overall"]
        totals.add_row("success rate", _fmt(100 * o["success_rate"]) + " %"
                       + (" (as recorded in the episodes' metadata)" if checked == "metadata" else ""))
        totals.add_row("mean steps to success", _fmt(o["mean_steps_to_success"]))
        totals.add_row("mean path length", _fmt(o["mean_path_length_cm"]) + " cm")

    features = Table(title="Features")
    for col in ("name", "dtype", "shape"):
        features.add_column(col)
    for name, ft in s["features"].items():
        features.add_row(name, ft["dtype"], "×".join(str(d) for d in ft["shape"]))

    parts = [totals, features]
    if s["has_provenance"]:
        # borderless so that ten columns still fit an 80-column terminal
        groups = Table(title="Provenance", box=box.SIMPLE_HEAD, pad_edge=False, collapse_padding=True,
                       caption="ok % = success rate; steps (to success) and path length averaged over "
                               "successful episodes; jaw = mean jaw closures")
        for col in GROUP_BY:
            # rich squeezes foldable columns first; keep ids readable (long ones fold instead of truncating)
            longest = max([len(str(g[col] or "–")) for g in s["groups"]] + [6])
            groups.add_column("operator" if col == "operator_id" else col, overflow="fold", min_width=min(longest, 12))
        for col in ("eps", "ok %", "steps", "path cm", "jaw"):
            groups.add_column(col, justify="right", no_wrap=True)
        for g in s["groups"]:
            groups.add_row(*(g[k] or "–" for k in GROUP_BY), str(g["episodes"]),
                           _fmt(100 * g["success_rate"]), _fmt(g["mean_steps_to_success"]),
                           _fmt(g["mean_path_length_cm"]), _fmt(g["mean_jaw_closures"], 2))
        parts.append(groups)
        if s["interventions"]:
            parts.append(_interventions_table(s["interventions"]))
        by_skill = facts["by_skill"]
        if by_skill:
            prof = Table(title="Proficiency by source and skill", box=box.SIMPLE_HEAD, pad_edge=False,
                         collapse_padding=True,
                         caption="steps (to success), path and LDLJ over successful episodes (mean ± std); "
                                 "LDLJ = log dimensionless jerk, higher is smoother; regrasp % = episodes with "
                                 "more than one jaw closure; clutch = mean clutch uses")
            for col in ("source", "skill", "eps", "ok %", "steps", "path cm", "LDLJ", "regrasp %", "clutch"):
                prof.add_column(col, justify="left" if col in ("source", "skill") else "right", no_wrap=True)
            for g in by_skill:
                prof.add_row(g["source"] or "–", g["skill"] or "–", str(g["episodes"]), _fmt(100 * g["success_rate"]),
                             f"{_fmt(g['mean_steps_to_success'])} ± {_fmt(g['std_steps_to_success'])}",
                             f"{_fmt(g['mean_path_length_cm'])} ± {_fmt(g['std_path_length_cm'])}",
                             _fmt(g["mean_ldlj"], 2), _fmt(100 * g["regrasp_rate"], 0), _fmt(g["mean_clutch_uses"], 2))
            parts.append(prof)
    return Group(*parts)


def _interventions_table(groups: list[dict]):
    from rich import box
    from rich.table import Table

    table = Table(title="Interventions by operator", box=box.SIMPLE_HEAD, pad_edge=False, collapse_padding=True,
                  caption="takeovers = times the operator took an arm over from the policy (two arms: PSM1 + PSM2 "
                          "in brackets); operator % = share of frames the operator drove (any arm); first = mean "
                          "time to the first takeover (episodes with one)")
    for col in ("source", "device", "skill", "operator", "eps", "takeovers", "per ep", "operator %", "first (s)"):
        table.add_column(col, justify="left" if col in ("source", "device", "skill", "operator") else "right",
                         no_wrap=col != "operator", overflow="fold")
    for g in groups:
        arms = g.get("arm_takeovers", [])
        takeovers = str(g["takeovers"]) + (f" ({' + '.join(map(str, arms))})" if len(arms) > 1 else "")
        table.add_row(*(g[k] or "–" for k in GROUP_BY), str(g["episodes"]), takeovers,
                      _fmt(g["takeovers_per_episode"], 2), _fmt(100 * g["intervention_share"], 0),
                      _fmt(g["time_to_takeover_s"]))
    return table


def render_info_text(root: str | Path, width: int = 120) -> str:
    """:func:`render_info` as plain text (logs, tests)."""
    import io

    from rich.console import Console

    console = Console(file=io.StringIO(), width=width, color_system=None, record=True)
    console.print(render_info(root))
    return console.export_text()
