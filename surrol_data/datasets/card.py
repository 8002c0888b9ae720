"""The dataset card: ``README.md`` inside a dataset, in Hugging Face's dataset-card format.

Made with lerobot's own card helper (``create_lerobot_dataset_card``: huggingface_hub's ``DatasetCardData`` for
the YAML front matter — license, task_categories, tags, size category and the parquet ``configs`` that the Hub
and ``datasets.load_dataset`` read — and lerobot's card template), so the card is what LeRobot users expect.
Its description holds what a user needs to trust the demos: the task, where the episodes came from (sources,
devices, operators, skills), counts, success and proficiency figures, the command lines that recorded them and
the frame structure. Only paths relative to the dataset appear: a card travels with the dataset, and the
recording machine's folders mean nothing elsewhere. The recorder writes it when it finalizes; merge / filter /
split write it for the datasets they make.
"""

from __future__ import annotations

import shlex
from collections import Counter
from pathlib import Path

from surrol_data.datasets.info import summarize

DEFAULT_LICENSE = "apache-2.0"
CARD_PATH = "README.md"
PAPER = ("Y. Long, W. Wei, T. Huang, Y. Wang and Q. Dou, *Human-in-the-loop Embodied Intelligence with Interactive "
         "Simulation Environment for Surgical Robot Learning*, IEEE Robotics and Automation Letters, 2023")
CITATION = """@article{long2023human,
  title   = {Human-in-the-loop Embodied Intelligence with Interactive Simulation Environment for Surgical Robot Learning},
  author  = {Long, Yonghao and Wei, Wang and Huang, Tao and Wang, Yuehao and Dou, Qi},
  journal = {IEEE Robotics and Automation Letters},
  year    = {2023}
}"""


def _fmt(value: float, fmt: str = "{:.1f}") -> str:
    return "–" if value != value else fmt.format(value)  # nan -> dash


def _size_category(rows: int) -> str:
    """Hugging Face's size category of a dataset of ``rows`` rows: a LeRobot dataset's rows are its frames."""
    for limit, label in ((1_000, "n<1K"), (10_000, "1K<n<10K"), (100_000, "10K<n<100K"), (1_000_000, "100K<n<1M"),
                         (10_000_000, "1M<n<10M")):
        if rows < limit:
            return label
    return "10M<n<100M"


def relative_command(command: str) -> str:
    """A recorded command line with absolute paths cut to their last part (``/home/me/data/NP`` → ``NP``), and
    a ``--opt=/abs/path`` likewise: the card must not publish the recording machine's folders."""
    try:
        tokens = shlex.split(command)
    except ValueError:
        return command
    out = []
    for token in tokens:
        key, eq, value = token.partition("=") if token.startswith("-") else ("", "", token)
        if value.startswith("/"):
            value = Path(value).name or value
        out.append(f"{key}{eq}{value}")
    return shlex.join(out)


def render_dataset_card(root: str | Path, license: str = DEFAULT_LICENSE, repo_id: str | None = None) -> str:
    """The card text of the dataset at ``root`` (see the module docstring); ``repo_id`` when it is on the Hub."""
    root = Path(root)
    s = summarize(root)
    side = s["sidecar"]
    task = side.get("task", ", ".join(s["tasks"]))
    lines = [f"Simulated da Vinci Research Kit demonstrations recorded with surrol_data "
             f"{side.get('package_version', '')} as a LeRobot {s['codebase_version']} dataset "
             f"(surrol_data schema {side.get('schema_version', '?')}).", "",
             "### Task", "",
             f"- task: **{task or '–'}**, env id `{side.get('env_id', '–')}`, robot `{s['robot_type'] or '–'}`",
             f"- instruction: \"{side.get('task_description', '')}\"",
             f"- {s['episodes']} episodes, {s['frames']} frames at {s['fps']} fps ({s['duration_s']:.0f} s)", ""]

    if s["has_provenance"] and s["episodes"]:
        from surrol_data.datasets.reader import DatasetReader

        eps = DatasetReader(root).episodes
        lines += ["### Sources", "", "| source | device | episodes |", "|---|---|---|"]
        for (src, dev), n in Counter(zip(eps["source"], eps["device"], strict=True)).most_common():
            lines.append(f"| {src} | {dev} | {n} |")
        lines += ["", "### Operators and skills", "", "| skill | operator | simulated | episodes |", "|---|---|---|---|"]
        for (skill, op, sim), n in Counter(zip(eps["skill"], eps["operator_id"], eps["operator_simulated"],
                                               strict=True)).most_common():
            lines.append(f"| {skill} | {op or '–'} | {'yes' if sim else 'no'} | {n} |")
        o = s["overall"]
        lines += ["", "### Proficiency", "",
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
        lines += ["### Derived from", "", f"{derived.get('operation', 'made')} of:", ""]
        lines += [f"- `{Path(src['root']).name}` ({src['episodes']} episodes)" for src in derived.get("sources", [])]
        if derived.get("where"):
            lines.append(f"- selection: `{derived['where']}`")
        lines.append("")
    commands = list(dict.fromkeys(relative_command(sess["command"]) for sess in side.get("sessions", [])
                                  if sess.get("command")))
    if commands:
        lines += ["### How it was made", "", "```", *commands, "```", ""]
    structure = ["[meta/info.json](meta/info.json) describes every feature; in short:", "",
                 "Per frame: `observation.state` and `observation.environment_state` (s_t: the robot state, then the "
                 "object/achieved goal and the desired goal, the inputs LeRobot policies such as ACT read), `action`, "
                 "`next.reward`, `next.done` (env terminated), `next.truncated` (ended without terminating), "
                 "`next.success`, `next.observation.*` (s_{t+1}), and `complementary_info.*` (tool-tip position in m, "
                 "jaw angle in rad, clutch and jaw buttons). Per episode: `provenance/*` columns in `meta/episodes` "
                 "(filter with LeRobot's `episode_filter`). Read with `surrol_data.datasets.reader.DatasetReader`; "
                 "check with `surrol-data validate`.", "",
                 "| feature | dtype | shape |", "|---|---|---|"]
    structure += [f"| `{k}` | {v['dtype']} | {tuple(v['shape'])} |" for k, v in s["features"].items()]

    from lerobot.datasets.utils import create_lerobot_dataset_card

    tags = ["surrol_data", "surgical-robotics", "dvrk", "pybullet"] + ([task] if task else [])
    card = create_lerobot_dataset_card(tags=tags, license=license, repo_id=repo_id or "",
                                       dataset_description="\n".join(lines), paper=PAPER, url="–",
                                       dataset_structure="\n".join(structure), citation_bibtex=CITATION)
    card.data.size_categories = [_size_category(s["frames"])]
    return str(card)


def write_dataset_card(root: str | Path, license: str = DEFAULT_LICENSE, repo_id: str | None = None) -> Path:
    """Write ``README.md`` (see :func:`render_dataset_card`) and return its path."""
    path = Path(root) / CARD_PATH
    path.write_text(render_dataset_card(root, license=license, repo_id=repo_id))
    return path
