"""The dataset card: ``README.md`` inside a dataset, in Hugging Face's dataset-card format.

A YAML front matter (license, task_categories, tags, configs — what the Hub indexes and what
``datasets.load_dataset`` reads to find the parquet files), then what a user needs to trust the demos: the
task, where the episodes came from (sources, devices, operators, skills), counts, success and proficiency
figures, the command lines that recorded them and the frame structure. The recorder writes it when it
finalizes; merge / filter / split write it for the datasets they make.
"""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from surrol_data.datasets.info import summarize

DEFAULT_LICENSE = "apache-2.0"
CARD_PATH = "README.md"


def _fmt(value: float, fmt: str = "{:.1f}") -> str:
    return "–" if value != value else fmt.format(value)  # nan -> dash


def render_dataset_card(root: str | Path, license: str = DEFAULT_LICENSE) -> str:
    """The card text of the dataset at ``root`` (see the module docstring)."""
    root = Path(root)
    s = summarize(root)
    side = s["sidecar"]
    task = side.get("task", ", ".join(s["tasks"]))
    tags = ["LeRobot", "surrol_data", "surgical-robotics", "dvrk", "pybullet"] + ([task] if task else [])
    size = "n<1K" if s["episodes"] < 1000 else "1K<n<10K" if s["episodes"] < 10_000 else "10K<n<100K"
    lines = ["---", "task_categories:", "- robotics", "tags:", *[f"- {t}" for t in tags],
             f"license: {license}", "size_categories:", f"- {size}",
             "configs:", "- config_name: default", "  data_files: data/*/*.parquet", "---", "",
             f"# {side.get('repo_id', root.name)}", "",
             f"Simulated da Vinci Research Kit demonstrations recorded with surrol_data "
             f"{side.get('package_version', '')} as a LeRobot {s['codebase_version']} dataset "
             f"(surrol_data schema {side.get('schema_version', '?')}).", "",
             "## Task", "",
             f"- task: **{task or '–'}**, env id `{side.get('env_id', '–')}`, robot `{s['robot_type'] or '–'}`",
             f"- instruction: \"{side.get('task_description', '')}\"",
             f"- {s['episodes']} episodes, {s['frames']} frames at {s['fps']} fps ({s['duration_s']:.0f} s)", ""]

    if s["has_provenance"] and s["episodes"]:
        from surrol_data.datasets.reader import DatasetReader

        eps = DatasetReader(root).episodes
        lines += ["## Sources", "", "| source | device | episodes |", "|---|---|---|"]
        for (src, dev), n in Counter(zip(eps["source"], eps["device"], strict=True)).most_common():
            lines.append(f"| {src} | {dev} | {n} |")
        lines += ["", "## Operators and skills", "", "| skill | operator | simulated | episodes |", "|---|---|---|---|"]
        for (skill, op, sim), n in Counter(zip(eps["skill"], eps["operator_id"], eps["operator_simulated"],
                                               strict=True)).most_common():
            lines.append(f"| {skill} | {op or '–'} | {'yes' if sim else 'no'} | {n} |")
        o = s["overall"]
        lines += ["", "## Proficiency", "",
                  f"Success rate {_fmt(100 * o['success_rate'])} %, mean steps to success "
                  f"{_fmt(o['mean_steps_to_success'])}, mean path length {_fmt(o['mean_path_length_cm'])} cm "
                  "(steps and path over successful episodes), mean jaw closures "
                  f"{_fmt(o['mean_jaw_closures'], '{:.2f}')}.", "",
                  "| source | device | skill | operator | episodes | success % | steps to success | path (cm) | jaw closures |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for g in s["groups"]:
            lines.append(f"| {g['source']} | {g['device']} | {g['skill']} | {g['operator_id'] or '–'} | "
                         f"{g['episodes']} | {_fmt(100 * g['success_rate'])} | {_fmt(g['mean_steps_to_success'])} | "
                         f"{_fmt(g['mean_path_length_cm'])} | {_fmt(g['mean_jaw_closures'], '{:.2f}')} |")
        lines.append("")
    derived = side.get("derived_from")
    if derived:
        lines += ["## Derived from", "", f"{derived.get('operation', 'made')} of:", ""]
        lines += [f"- `{src['root']}` ({src['episodes']} episodes)" for src in derived.get("sources", [])]
        if derived.get("where"):
            lines.append(f"- selection: `{derived['where']}`")
        lines.append("")
    commands = list(dict.fromkeys(sess.get("command", "") for sess in side.get("sessions", []) if sess.get("command")))
    if commands:
        lines += ["## How it was made", "", "```", *commands, "```", ""]
    lines += ["## Structure", "",
              "Per frame: `observation.*` (s_t), `action`, `next.reward`, `next.done` (env terminated), "
              "`next.success`, `next.observation.*` (s_{t+1}), and `complementary_info.*` (tool-tip position in m, "
              "jaw angle in rad, clutch and jaw buttons). Per episode: `provenance/*` columns in `meta/episodes` "
              "(filter with LeRobot's `episode_filter`). Read with `surrol_data.datasets.reader.DatasetReader`; "
              "check with `surrol-data validate`.", "",
              "| feature | dtype | shape |", "|---|---|---|"]
    lines += [f"| `{k}` | {v['dtype']} | {tuple(v['shape'])} |" for k, v in s["features"].items()]
    return "\n".join(lines) + "\n"


def write_dataset_card(root: str | Path, license: str = DEFAULT_LICENSE) -> Path:
    """Write ``README.md`` (see :func:`render_dataset_card`) and return its path."""
    path = Path(root) / CARD_PATH
    path.write_text(render_dataset_card(root, license=license))
    return path
