"""``surrol-data``: the command line of the toolkit (one sub-command per job)."""

from __future__ import annotations

import contextlib
import shlex
import sys
from enum import Enum
from pathlib import Path
from typing import Optional


import typer  # noqa: E402
from rich.console import Console  # noqa: E402
from rich.markup import escape  # noqa: E402

app = typer.Typer(add_completion=False, no_args_is_help=True, pretty_exceptions_show_locals=False,
                  help="Surgical-robot learning from demonstrations that know where they came from.")
console = Console()


class Source(str, Enum):
    script = "script"
    haptic = "haptic"
    intervene = "intervene"


def _fail(message: str) -> None:
    # the message is text, not markup: `pip install 'surrol-data[export]'` must keep its [export]
    console.print(f"[bold red]error:[/] {escape(message)}", highlight=False)
    raise typer.Exit(code=2)


def _write_error(error: BaseException | None) -> OSError | None:
    """The failed file-system call behind ``error`` (itself, or an error it was raised from: lerobot and pyarrow wrap
    them), when it is one of a disk's own failures (full, quota, read-only, I/O error, no permission); else None."""
    from surrol_data.datasets.write_failure import disk_error

    return disk_error(error)


def _disk_full(error: BaseException | None) -> bool:
    """Whether ``error`` (or an error it was raised from) is a failed write of the disk (see :func:`_write_error`)."""
    return _write_error(error) is not None


@contextlib.contextmanager
def _disk_full_is_an_error(path: Path, kept=None):
    """A failed write (a full disk, a read-only one, an I/O error) ends the command with one line, not a traceback,
    that names what is kept and how to go on: ``kept()`` says it for this command (default: a dataset ``path`` a
    recording or a repair was writing, see :func:`surrol_data.datasets.write_failure.what_is_kept`; it is given the
    error). What was written
    is safe (episodes are journalled before ``record`` returns, files are replaced only once their new version is
    whole), so saying so is true."""
    try:
        yield
    except typer.Exit:  # a RuntimeError too (click's Exit): the command has already said why it stopped
        raise
    except Exception as e:  # noqa: BLE001 - only a failed write is handled here; anything else is re-raised
        error = _write_error(e)
        if error is None:
            raise
        from surrol_data.datasets.write_failure import describe, what_is_kept

        _fail(f"{describe(error)} while writing {path}: stopped; "
              f"{kept(error) if kept is not None else what_is_kept(path, error)}")


def _inputs_unchanged(out: Path):
    from surrol_data.datasets.write_failure import what_is_kept

    return lambda error: what_is_kept(out, error, inputs="the inputs are unchanged")


def _split_kept(out: Path):
    from surrol_data.datasets.write_failure import what_is_kept

    def kept(error) -> str:
        parts = [what_is_kept(out / name, error, inputs="the input is unchanged") for name in ("train", "valid")
                 if (out / name / "meta").is_dir()]
        return " ".join(parts) or what_is_kept(out, error, inputs="the input is unchanged")

    return kept


def _upgrade_kept(dataset: Path):
    from surrol_data.datasets.write_failure import remedy

    return lambda error: (f"{dataset} is unchanged (the upgrade is built beside it and swapped in only once whole); "
                          f"{remedy(error)}, then run the command again")


def _each_file_whole(dataset: Path):
    from surrol_data.datasets.write_failure import remedy

    return lambda error: (f"every file of {dataset} is whole, the old version or the new one (each is replaced "
                          f"only once written); {remedy(error)}, then run the command again")


def _export_kept(out: Path, dataset: Path):
    from surrol_data.datasets.write_failure import remedy

    return lambda error: (f"nothing was written to {out} (a partial export never takes its name) and {dataset} is "
                          f"unchanged; {remedy(error)}, then run the command again")


@contextlib.contextmanager
def _ctrl_c_says_what_is_kept(out: Path):
    """Ctrl-C ends a recording (the recorder has finalized every episode finished before it, on the way out) with
    what the dataset holds and how to go on, not a silent exit."""
    try:
        yield
    except KeyboardInterrupt:
        import json

        info = out / "meta" / "info.json"
        held = json.loads(info.read_text()).get("total_episodes", 0) if info.is_file() else 0
        Console(stderr=True).print(f"stopped by Ctrl-C: {out} holds {held} episodes, every one finished before the "
                                   "stop; run the same command with --append to record more", highlight=False,
                                   soft_wrap=True)
        raise typer.Exit(130) from None


def _note(message: str) -> None:
    """Something the user should know that is not an error (e.g. an automatic repair)."""
    Console(stderr=True).print(f"[yellow]note:[/] {escape(message)}", highlight=False)


# ---------------------------------------------------------------- the grammar every command shares
# A dataset is a positional argument; what a command writes is --out; --episodes is always episode indices
# (0,3,5-9) and --num-episodes a count. Anything that can take more than ~2 s shows progress on stderr.

def _episode_indices(spec: Optional[str]) -> Optional[list[int]]:
    from surrol_data.datasets.episode_ranges import parse_episode_ranges

    if spec is None:
        return None
    try:
        return parse_episode_ranges(spec)
    except ValueError as e:
        _fail(str(e))


def _count(num_episodes: Optional[int], old_episodes: Optional[int], default: Optional[int] = None) -> int:
    """--num-episodes, or the deprecated --episodes N of earlier versions (with a note), or ``default``."""
    if old_episodes is not None:
        if num_episodes is not None:
            _fail("give the number of episodes once, with --num-episodes (--episodes N is its old name)")
        _note(f"--episodes N (a count) is deprecated here: write --num-episodes {old_episodes}; --episodes now "
              "always means episode indices such as 0,3,5-9")
        return old_episodes
    if num_episodes is None:
        if default is None:
            _fail("say how many episodes: --num-episodes N")
        return default
    return num_episodes


def _old_count_option():
    return typer.Option(None, "--episodes", hidden=True, min=1, help="Deprecated: the old name of --num-episodes.")


@contextlib.contextmanager
def _stages(title: str, stages: tuple[str, ...]):
    """A progress bar over named stages: ``with _stages(...) as stage: stage("name")`` as each one starts."""
    from rich.progress import BarColumn, Progress, SpinnerColumn, TextColumn, TimeElapsedColumn

    with Progress(SpinnerColumn(), TextColumn("{task.description}"), BarColumn(), TimeElapsedColumn(),
                  console=Console(stderr=True), transient=True) as progress:
        task = progress.add_task(title, total=len(stages))
        started: list[str] = []

        def stage(name: str) -> None:
            if started:
                progress.advance(task)
            started.append(name)
            progress.update(task, description=f"{title}: {name}")

        yield stage


def _working(message: str):
    """A spinner on stderr while a single long step runs."""
    return Console(stderr=True).status(message)


def _supervised_policy(spec: Optional[str]) -> tuple:
    """(the policy, what provenance records of it) of an intervention session's ``--policy``; (None, None) without."""
    if spec is None:
        return None, None
    from surrol_data.algos.policies import describe_policy, load_policy

    try:
        return load_policy(spec), describe_policy(spec)
    except (ValueError, FileNotFoundError) as e:
        _fail(f"--policy: {e}")


def _camera_size(camera: bool, camera_size: Optional[str]) -> Optional[tuple[int, int]]:
    if camera_size is not None and not camera:
        camera = True  # --camera-size alone asks for the camera too
    if not camera:
        return None
    spec = camera_size or "128x128"
    try:
        w, h = (int(v) for v in spec.lower().split("x"))
    except ValueError:
        _fail(f"--camera-size takes WIDTHxHEIGHT in pixels, e.g. 128x128; got {spec!r}")
    if not (8 <= w <= 2048 and 8 <= h <= 2048):
        _fail(f"--camera-size: {spec} is outside 8..2048 pixels per side")
    return w, h


def _camera_renderer(renderer: Optional[str], size: Optional[tuple[int, int]]) -> str:
    """``--renderer``: a renderer the envs know (checked before any env or dataset exists); only with the camera."""
    from surrol_data.datasets.schema import DEFAULT_CAMERA_RENDERER

    if renderer is None:
        return DEFAULT_CAMERA_RENDERER
    if size is None:
        _fail("--renderer chooses what draws the endoscope video: add --camera (it records no video without)")
    from surrol_data.envs.camera import camera_renderers

    choices = camera_renderers()
    if renderer not in choices:
        _fail(f"--renderer must be one of {', '.join(choices)}; got {renderer!r}")
    if renderer == "panda3d":   # can it draw here? Said now, in this command's words, before any dataset exists
        from surrol_data.extras import MissingExtra, require

        try:
            require("panda3d")
        except MissingExtra as e:
            _fail(str(e))
        from surrol_data.render.display import in_words_of, unavailable_reason

        why = unavailable_reason()
        if why is not None:
            _fail(in_words_of(why, ", or draw with TinyRenderer (--renderer tiny)"))
    return renderer


@app.command()
def demo(out: Optional[Path] = typer.Option(None, help="Folder for everything the demo makes (default: a new temp folder)."),
         num_episodes: Optional[int] = typer.Option(None, min=1, help="Scripted demos to collect (default 20)."),
         eval_episodes: int = typer.Option(20, min=1, help="Evaluation episodes per policy."),
         seed: int = typer.Option(0, help="First demo seed."),
         old_episodes: Optional[int] = _old_count_option()):
    """Quick end-to-end run: collect NeedlePick script demos, train BC, evaluate, write a report and a Rerun file."""
    from surrol_data.demo import run_demo

    episodes = _count(num_episodes, old_episodes, default=20)
    try:
        run_demo(out, episodes=episodes, eval_episodes=eval_episodes, seed=seed, console=console)
    except FileExistsError as e:
        _fail(str(e))


class Launcher(str, Enum):
    local = "local"
    slurm = "slurm"


def _slurm_options(partition, account, time_min, mem_gb, cpus, sbatch):
    from surrol_data.slurm import SlurmOptions, parse_sbatch_options

    try:
        return SlurmOptions(partition=partition, account=account, time_min=time_min, mem_gb=mem_gb,
                            cpus_per_task=cpus, extra=parse_sbatch_options(sbatch))
    except ValueError as e:
        _fail(str(e))


# The SLURM options of the commands that can fan out over a cluster (study, collect --shards).
def _partition_option():
    return typer.Option(None, help="--launcher slurm: the SLURM partition (sinfo lists them; default: the "
                                   "cluster's default).")


def _account_option():
    return typer.Option(None, help="--launcher slurm: the account to charge (sbatch --account).")


def _time_option(default: int):
    return typer.Option(default, "--time", min=1, help="--launcher slurm: each job's time limit in minutes.")


def _mem_option(default: float):
    return typer.Option(default, "--mem-gb", min=0.1, help="--launcher slurm: each job's memory in GB.")


def _cpus_option(default: int):
    return typer.Option(default, "--cpus", min=1, help="--launcher slurm: CPUs per job.")


def _sbatch_option():
    return typer.Option([], help="--launcher slurm: a further sbatch option KEY=VALUE, e.g. qos=normal "
                                 "(repeatable).")


def _collect_shards(source, task, episodes, out, shards, launcher, seed, append, command, slurm_options,
                    kwargs) -> None:
    from surrol_data.collect.shards import collect_script_shards
    from surrol_data.datasets.reader import DatasetError
    from surrol_data.extras import MissingExtra
    from surrol_data.slurm import SlurmError

    if source is not Source.script:
        _fail("--shards and --launcher slurm record scripted demos: use them with --source script")
    if shards is None:
        _fail("--launcher slurm collects in shards: add --shards N (one SLURM job per shard)")
    if append:
        _fail("--shards records new shards and merges them into a new dataset: leave out --append (merge the "
              "result into an existing dataset with `surrol-data merge`)")
    from surrol_data.datasets.write_failure import what_is_kept

    def kept(error) -> str:
        return f"the shards recorded so far are kept in {out}.shards (each a dataset); " + what_is_kept(out, error)

    with _disk_full_is_an_error(out, kept):
        try:
            collect_script_shards(task, episodes, out, shards, seed=seed or 0, command=command, say=console.print,
                                  slurm=slurm_options if launcher is Launcher.slurm else None, **kwargs)
        except (ValueError, FileExistsError, RuntimeError, DatasetError, SlurmError, MissingExtra) as e:
            if _disk_full(e):
                raise
            _fail(str(e))
    console.print(f"recorded {episodes} episodes in {shards} shard(s) (disjoint seeds; kept in {out}.shards) and "
                  f"merged them into {out}")


@app.command()
def collect(source: Source = typer.Option(..., help="Where actions come from: the scripted oracle, a teleoperation "
                                          "device, or a policy that the operator of a device takes over (intervene)."),
            task: str = typer.Option(..., help="Task name, e.g. NeedlePick (see `surrol-data tasks`)."),
            num_episodes: Optional[int] = typer.Option(None, min=1, help="Episodes to record (kept ones)."),
            out: Path = typer.Option(..., help="Dataset folder (must not exist unless --append)."),
            camera: bool = typer.Option(False, help="Also record the endoscope view as video "
                                                    "(observation.images.endoscope)."),
            camera_size: Optional[str] = typer.Option(None, help="Endoscope image WIDTHxHEIGHT with --camera "
                                                                 "(default 128x128)."),
            renderer: Optional[str] = typer.Option(None, help="What draws the endoscope video with --camera: tiny "
                                                   "(PyBullet's TinyRenderer, the default) or panda3d (spotlight, "
                                                   "shadows; offscreen through EGL). Recorded in the dataset."),
            seed: Optional[int] = typer.Option(None, help="Seed of the first attempt; attempt i uses seed + i "
                                               "(default 0; with --append, one past the dataset's last seed)."),
            max_steps: Optional[int] = typer.Option(None, min=1, help="Episode horizon (default: the task's)."),
            keep_failures: bool = typer.Option(False, help="Also record episodes that never succeeded."),
            append: bool = typer.Option(False, help="Add episodes to an existing dataset."),
            device: str = typer.Option("touch", help="haptic: touch, keyboard, gamepad, spacemouse, replay or operator."),
            operator_id: str = typer.Option("", help="haptic: who operates (recorded in provenance)."),
            skill: str = typer.Option("unknown", help="haptic: expert, novice or unknown (operator: expert|novice)."),
            side: Optional[list[str]] = typer.Option(None, help="haptic: device side per arm (left/right); repeat "
                                                     "for bimanual tasks (default right→PSM1, left→PSM2)."),
            mapping: Optional[list[str]] = typer.Option(None, help="haptic: mapping override NAME=VALUE, e.g. "
                                                        "motion_scale=0.4 or axis_sign=1,-1,1 (repeatable)."),
            trace: Optional[Path] = typer.Option(None, help="haptic replay: a device trace, or a haptic dataset."),
            gui: Optional[bool] = typer.Option(None, "--gui/--no-gui", help="haptic: PyBullet window (default: "
                                               "with a display, for human devices)."),
            rerun_live: Optional[str] = typer.Option(None, help="haptic: stream to Rerun: 'spawn', a "
                                                     "rerun+http:// URL or an .rrd path."),
            profile: Optional[str] = typer.Option(None, help="haptic operator: profile other than the skill's "
                                                  "natural one, e.g. expert_matched (the paper's demo pace)."),
            speed: float = typer.Option(1.0, min=0.01, max=1.0, help="script: the oracle's pace (0.3 matches the "
                                        "paper's script demos at --max-steps 150)."),
            policy: Optional[str] = typer.Option(None, help="intervene: the policy that acts: a checkpoint (.pt), "
                                                 "lerobot:DIR or 'oracle'."),
            shards: Optional[int] = typer.Option(None, min=1, help="script: record in N shards at once (disjoint "
                                                 "seeds; local worker processes, or SLURM jobs with --launcher "
                                                 "slurm), kept in OUT.shards/, then merged into OUT."),
            workers: int = typer.Option(1, min=1, help="script: roll the episodes out in N processes while this "
                                        "one records them, in seed order (the same dataset whatever N)."),
            launcher: Launcher = typer.Option(Launcher.local, help="--shards: where the shards run."),
            partition: Optional[str] = _partition_option(),
            account: Optional[str] = _account_option(),
            time_min: int = _time_option(60),
            mem_gb: float = _mem_option(2.0),
            cpus: int = _cpus_option(1),
            sbatch: list[str] = _sbatch_option(),
            old_episodes: Optional[int] = _old_count_option()):
    """Record demonstrations into a LeRobot v3 dataset with per-episode provenance (and the endoscope video)."""
    command = shlex.join(["surrol-data", *sys.argv[1:]])
    episodes = _count(num_episodes, old_episodes)
    size = _camera_size(camera, camera_size)
    drawn_by = _camera_renderer(renderer, size)
    from surrol_data.extras import MissingExtra   # --renderer panda3d without Panda3D installed
    if (policy is not None) != (source is Source.intervene):
        _fail("--policy names the policy of --source intervene (and only of it)" if policy is not None else
              "--source intervene needs --policy: a checkpoint (.pt), lerobot:DIR or 'oracle'")
    if workers > 1 and (source is not Source.script or shards is not None or launcher is Launcher.slurm):
        _fail("--workers runs the scripted oracle's episodes in parallel: it needs --source script, without --shards")
    if shards is not None or launcher is Launcher.slurm:   # it says these need --source script
        _collect_shards(source, task, episodes, out, shards, launcher, seed, append, command,
                        _slurm_options(partition, account, time_min, mem_gb, cpus, sbatch),
                        dict(max_steps=max_steps, keep_failures=keep_failures, camera_size=size, speed=speed,
                             camera_renderer=drawn_by))
        return
    if source is not Source.script:
        from surrol_data.collect.devices import DeviceError
        from surrol_data.collect.haptic_source import collect_haptic, parse_mapping
        from surrol_data.collect.script_source import camera_kwargs

        acting, policy_info = _supervised_policy(policy)
        with _ctrl_c_says_what_is_kept(out), _disk_full_is_an_error(out):
            try:
                result = collect_haptic(task, episodes, out, device=device, operator_id=operator_id, skill=skill,
                                        sides=side or None, mapping=parse_mapping(mapping or []), trace=trace,
                                        seed=seed, max_steps=max_steps, keep_failures=keep_failures, append=append,
                                        gui=gui, rerun_live=rerun_live, command=command,
                                        env_kwargs=camera_kwargs(size, drawn_by), profile=profile, policy=acting,
                                        policy_info=policy_info)
            except (ValueError, FileExistsError, RuntimeError, MissingExtra) as e:   # DeviceError is a RuntimeError
                if _disk_full(e):
                    raise
                _fail(str(e) if not isinstance(e, DeviceError) else f"device: {e}")
        console.print(f"recorded {result.kept} episodes ({result.attempts} attempts, success "
                      f"{result.success_rate:.0%}, {result.discarded} discarded, {result.redone} redone) into {out}")
        if policy is not None:
            console.print(f"the operator took over {result.takeovers} times and drove {result.intervention_frames} "
                          f"of {result.frames} frames")
        return
    from surrol_data.collect.script_source import collect_script

    with _ctrl_c_says_what_is_kept(out), _disk_full_is_an_error(out):
        try:
            result = collect_script(task, episodes, out, seed=seed, max_steps=max_steps, keep_failures=keep_failures,
                                    append=append, command=command, camera_size=size, speed=speed,
                                    workers=workers, camera_renderer=drawn_by)
        except (ValueError, FileExistsError, RuntimeError, MissingExtra) as e:
            if _disk_full(e):
                raise
            _fail(str(e))
    console.print(f"recorded {result.kept} episodes ({result.attempts} attempts, oracle success "
                  f"{result.success_rate:.0%}) into {out}")


@app.command()
def gui(out: Path = typer.Option(Path("gui_sessions"), help="Folder for the sessions' datasets: OUT/<task>."),
        task: Optional[str] = typer.Option(None, help="Task chosen when the window opens."),
        device: str = typer.Option("keyboard", help="keyboard, operator, touch, gamepad or spacemouse."),
        operator_id: str = typer.Option("", help="Who operates (recorded in provenance)."),
        skill: str = typer.Option("unknown", help="expert, novice or unknown (operator: expert|novice)."),
        seed: int = typer.Option(0, help="Seed of the first attempt; attempt i uses seed + i."),
        autoplay: Optional[int] = typer.Option(None, min=1, help="Play --task at once and exit after this many "
                                               "saved episodes (demos, smoke tests)."),
        screenshot: Optional[Path] = typer.Option(None, help="Write a PNG of the window when it closes."),
        policy: Optional[str] = typer.Option(None, help="A policy that acts while you supervise (a checkpoint, "
                                             "lerobot:DIR or 'oracle'): hold 'take over' to drive."),
        offscreen: Optional[bool] = typer.Option(None, "--offscreen/--onscreen", help="Draw into an offscreen "
                                                 "buffer (default: when there is no display).")):
    """The training GUI: pick a task, press play, operate with any device; every attempt is recorded with provenance."""
    from surrol_data.extras import MissingExtra, require

    try:
        require("panda3d")
    except MissingExtra as e:
        _fail(f"the GUI: {e}")
    from surrol_data.collect.haptic_source import SKILLS
    from surrol_data.envs import TASKS
    from surrol_data.gui.app import DEVICES
    from surrol_data.render.display import RendererUnavailable, in_words_of, no_window_here

    # The options first (a wrong one is wrong on any machine), then whether a window can open here.
    if task is not None and task not in TASKS:
        _fail(f"unknown task {task!r}; known tasks: {', '.join(TASKS)}")
    if device not in DEVICES:
        _fail(f"--device must be one of {', '.join(DEVICES)}, got {device!r}")
    if skill not in SKILLS:
        _fail(f"--skill must be one of {', '.join(SKILLS)}, got {skill!r}")
    if autoplay is not None and task is None:
        _fail("--autoplay needs --task")
    refusal = no_window_here(offscreen, runs_alone=autoplay is not None)
    if refusal is not None:
        _fail(refusal)
    from surrol_data.gui.app import TrainingApp

    acting, policy_info = _supervised_policy(policy)
    try:
        window = TrainingApp(out, offscreen=offscreen, seed=seed, policy=acting, policy_info=policy_info)
    except RendererUnavailable as e:
        _fail(in_words_of(str(e), ""))   # the GUI draws with Panda3D only
    window.set_session(device, skill, operator_id)
    if task is not None:
        window.choose_task(task)
    if autoplay is not None:
        window.autoplay(task, autoplay)
    window.run(screenshot=screenshot)
    if window.last_error:
        _fail(window.last_error)
    if window.last_result is not None:
        r = window.last_result
        console.print(f"recorded {r.kept} episodes ({r.attempts} attempts, {r.discarded} discarded, "
                      f"{r.redone} redone) into {out / window.last_task}")


@app.command()
def serve(out: Path = typer.Option(..., help="Folder for the datasets: OUT/<task>, one per task, appended to."),
          task: Optional[list[str]] = typer.Option(None, help="A task offered (repeat for more; default: every "
                                                   "task). The first is chosen when a page opens."),
          host: str = typer.Option("127.0.0.1", help="Address to listen on: 127.0.0.1 (this machine only), "
                                   "0.0.0.0 for the network (browsers still need the printed token)."),
          port: int = typer.Option(8765, min=0, max=65535, help="Port (0: a free one)."),
          token: Optional[str] = typer.Option(None, envvar="SURROL_DATA_WEB_TOKEN",
                                              help="Access token browsers need (default: a new random one, printed "
                                              "with the address); from the environment, it stays out of `ps`."),
          view_size: str = typer.Option("640x480", help="Endoscope view WIDTHxHEIGHT streamed to each browser "
                                        "(at most 1280x960)."),
          renderer: str = typer.Option("auto", help="What draws the view: auto (Panda3D where it can render, "
                                       "else TinyRenderer), panda3d or tiny.")):
    """A web console for human demonstrations: every browser drives its own env; episodes into OUT/<task>."""
    from surrol_data.envs import TASKS
    from surrol_data.extras import MissingExtra, require

    try:
        for module in ("starlette", "uvicorn", "websockets"):
            require(module)
    except MissingExtra as e:
        _fail(f"serve: {e}")
    tasks = list(dict.fromkeys(task or TASKS))
    unknown = [t for t in tasks if t not in TASKS]
    if unknown:
        _fail(f"unknown task {unknown[0]!r}; known tasks: {', '.join(TASKS)}")
    try:
        size = tuple(int(v) for v in view_size.lower().split("x"))
    except ValueError:
        size = ()
    if len(size) != 2 or not (64 <= size[0] <= 1280 and 64 <= size[1] <= 960):
        _fail(f"--view-size takes WIDTHxHEIGHT from 64x64 to 1280x960, e.g. 640x480; got {view_size!r}")
    if renderer not in ("auto", "panda3d", "tiny"):
        _fail(f"--renderer must be auto, panda3d or tiny, got {renderer!r}")
    if token is not None and len(token) < 8:
        _fail("--token must be at least 8 characters")
    from surrol_data.web import serve as serve_console

    try:
        serve_console(out, tasks, host=host, port=port, token=token, size=size, renderer=renderer,
                      announce=lambda line: print(line, flush=True))
    except OSError as e:
        _fail(f"cannot listen on {host}:{port}: {e.strerror or e} (another server there? try --port 0)")


@app.command()
def info(dataset: Path = typer.Argument(..., help="Dataset folder.")):
    """Summarise a dataset: counts, features and a provenance breakdown."""
    from surrol_data.datasets.info import render_info
    from surrol_data.datasets.info_cache import checked_info
    from surrol_data.datasets.reader import DatasetError

    try:
        with _working(f"checking and summarising {dataset} ..."), _disk_full_is_an_error(dataset):
            target, facts = checked_info(dataset, _note)   # the same bytes answered before: remembered
            summary = render_info(target, label=dataset, facts=facts)
        console.print(summary)
    except DatasetError as e:
        _fail(str(e))


@app.command("eval")
def evaluate_cmd(task: str = typer.Option(..., help="Task name, e.g. NeedlePick."),
                 policy: str = typer.Option("oracle", help="'oracle', 'lerobot:DIR' (a policy trained by lerobot-train), "
                                                           "'robomimic:CKPT' (a robomimic checkpoint .pth), "
                                                           "the path of a BC checkpoint (.pt), or a run or sweep "
                                                           "folder: every policy.pt under it."),
                 num_episodes: Optional[int] = typer.Option(None, min=1, help="Episodes to run (default 20)."),
                 seed: Optional[int] = typer.Option(None, help="Seed of the first episode; episode i uses seed + i "
                                                               "(default: 1,000,000,000, never a demo's seed)."),
                 max_steps: Optional[int] = typer.Option(None, min=1),
                 out: Optional[Path] = typer.Option(None, help="JSON file recording task, policy, seeds, summary "
                                                                "and every episode's metrics (a list for a folder)."),
                 old_episodes: Optional[int] = _old_count_option()):
    """Run a policy (or every run's policy under a folder) for N seeded episodes (unseen seeds by default) and
    print the proficiency metrics."""
    import json

    episodes = _count(num_episodes, old_episodes, default=20)

    from surrol_data.algos.policies import load_policy
    from surrol_data.demo import print_summary
    from surrol_data.envs import env_id
    from surrol_data.evaluation.rollout import EVAL_SEED_BASE, evaluate

    first = EVAL_SEED_BASE if seed is None else seed
    folder = Path(policy) if policy != "oracle" and Path(policy).is_dir() else None
    specs = sorted(str(p) for p in folder.rglob("policy.pt")) if folder else [policy]
    if not specs:
        _fail(f"{policy} holds no policy.pt: give a training run or sweep folder (runs/...), a checkpoint or 'oracle'")
    records, summaries = [], {}
    for spec in specs:
        try:
            result = evaluate(env_id(task), load_policy(spec), episodes, seed=first, max_steps=max_steps)
        except (ValueError, FileNotFoundError) as e:
            _fail(str(e))
        summaries[f"{spec} on {task}"] = result.summary
        records.append(_nan_to_null(result.as_record(spec)))
    print_summary(console, summaries)
    console.print(f"seeds {first}..{first + episodes - 1}")
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(records if folder else records[0], indent=2, allow_nan=False))
        console.print(f"wrote {out}")


@app.command()
def assess(dataset: Path = typer.Argument(..., help="Dataset folder."),
           out: Optional[Path] = typer.Option(None, help="Folder for assessment.md, assessment.png and episodes.csv.")):
    """Demo proficiency per operator and skill, against the expert benchmark (proficiency-based progression)."""
    from rich.markdown import Markdown

    from surrol_data.datasets.guard import require_valid
    from surrol_data.datasets.reader import DatasetError
    from surrol_data.evaluation.assess import (assess_dataset, assessment_columns, assessment_notes, assessment_rows,
                                               assessment_title, write_assessment)
    from surrol_data.evaluation.terminal_table import terminal_table

    try:
        require_valid(dataset, _note)
        with console.status(f"scoring the episodes of {dataset} ..."):
            result = assess_dataset(dataset)
    except (DatasetError, ValueError, FileNotFoundError) as e:
        _fail(str(e))
    console.print(Markdown(f"# {assessment_title(result)}"))
    # whole headers at 80 columns
    console.print(terminal_table(console, assessment_rows(result), assessment_columns(result)))
    console.print(Markdown(assessment_notes(result)))
    if out is not None:
        files = write_assessment(result, out)
        console.print(f"wrote {', '.join(str(p) for p in files.values())}")


@app.command()
def report(runs: list[Path] = typer.Argument(..., help="Training run folders, or folders that contain them."),
           out: Path = typer.Option(..., help="Folder for report.md, report.html and learning_curves.png."),
           epochs: Optional[str] = typer.Option(None, help="The table's two epochs, e.g. '50,100' (default: the "
                                                            "paper's 50 and 100 when the runs are that long)."),
           demos: list[Path] = typer.Option([], help="Demo datasets to add a demo-quality table for (repeatable).")):
    """The demo-source study report: Table I layout beside the paper's figures, learning curves, provenance."""
    from surrol_data.datasets.reader import DatasetError
    from surrol_data.evaluation.assess import ASSESS_COLUMNS, assess_dataset
    from surrol_data.evaluation.report import metrics_table_markdown
    from surrol_data.evaluation.study_report import StudyReportError, write_study_report

    try:
        at = [int(e) for e in epochs.split(",")] if epochs else None
    except ValueError:
        _fail(f"--epochs takes whole numbers separated by commas, e.g. 50,100; got {epochs!r}")
    from surrol_data.datasets.guard import require_valid

    try:
        demo_rows = []
        for path in demos:
            require_valid(path, _note)
            demo_rows += [{**row, "group": f"{path.name}: {row['group']}"}
                          for row in assess_dataset(path).skills.to_dict("records")]
        with console.status("writing the report ..."):
            files = write_study_report(runs, out, epochs=at, command=_this_command(),
                                       demo_table_markdown=metrics_table_markdown(demo_rows, ASSESS_COLUMNS)
                                       if demo_rows else None)
    except (StudyReportError, DatasetError, ValueError, FileNotFoundError) as e:
        _fail(str(e))
    console.print(f"wrote {files['markdown']}, {files['html']} and {files['curves']}")


def _print_run_jobs(rows) -> None:
    from rich.table import Table

    from surrol_data.study.spec import run_name

    table = Table(title="SLURM jobs of the study")
    for col in ("run", "state", "job", "log"):
        table.add_column(col, overflow="fold")
    for r in rows:
        colour = {"finished": "green", "failed": "bold red"}.get(r.state, "yellow")
        table.add_row(run_name(*r.run), f"[{colour}]{r.state}[/]", r.job_id, r.log if r.state == "failed" else "")
    console.print(table)
    failed = [run_name(*r.run) for r in rows if r.state == "failed"]
    if failed:
        console.print(f"failed (see the logs): {', '.join(failed)}; the same --launcher slurm command submits them "
                      "again, resuming from their checkpoints")


@app.command()
def study(experiment: str = typer.Argument(..., help="A study experiment config: table1 or table1_quick."),
          out: Path = typer.Option(..., help="Folder for the runs and the report (e.g. docs/results/table1)."),
          next_runs: Optional[int] = typer.Option(None, "--next", min=1,
                                                  help="Train the next N runs not finished yet (a fixed order that "
                                                       "interleaves sources and seeds), then rebuild the report."),
          runs: Optional[str] = typer.Option(None, help="Train these runs, e.g. expert/0,novice/1."),
          report_only: bool = typer.Option(False, "--report", help="Train nothing: rebuild the report from the "
                                                                   "finished runs (and show the SLURM jobs' states)."),
          build_demos: bool = typer.Option(False, help="Build the study's shipped demo sets (datasets/…) and their "
                                                       "manifest first."),
          check_code: bool = typer.Option(False, help="Record this checkout's code identity on this machine in "
                                                      "OUT/code_checks.jsonl and check it against the finished runs."),
          natural: bool = typer.Option(False, help="Use the operators' natural pace instead of demo sets matched "
                                                   "to the paper's."),
          override: list[str] = typer.Option([], help="Hydra override for every run, e.g. algo=ddpgbc_warm "
                                                      "(repeatable)."),
          launcher: Launcher = typer.Option(Launcher.local, help="local: train the runs here as one batch; slurm: "
                                            "submit one SLURM job per run (a job array) and return."),
          wait: bool = typer.Option(False, help="--launcher slurm: wait for the jobs, then write the report."),
          partition: Optional[str] = _partition_option(),
          account: Optional[str] = _account_option(),
          time_min: int = _time_option(1440),
          mem_gb: float = _mem_option(4.0),
          cpus: int = _cpus_option(3),
          sbatch: list[str] = _sbatch_option()):
    """The Table I study, run by run: train pending runs (all, --next N or --runs), then report on the finished."""
    from surrol_data.datasets.reader import DatasetError
    from surrol_data.evaluation.study_report import StudyReportError
    from surrol_data.slurm import SlurmError
    from surrol_data.study import run_study
    from surrol_data.study.cluster import run_jobs, submit_study, submitted_jobs, wait_for_runs
    from surrol_data.study.runs import study_spec

    if sum(x is not None and x is not False for x in (next_runs, runs, report_only or None)) > 1:
        _fail("--next, --runs and --report choose what to train: give one of them")
    slurm = launcher is Launcher.slurm
    if slurm and (report_only or check_code):
        _fail("--launcher slurm submits runs; --report and --check-code run here: leave out --launcher slurm")
    if wait and not slurm:
        _fail("--wait waits for SLURM jobs: add --launcher slurm")
    from surrol_data.extras import MissingExtra

    errors = (StudyReportError, DatasetError, ValueError, FileNotFoundError, RuntimeError, SlurmError, MissingExtra)
    failed = False
    try:
        if slurm:
            options = _slurm_options(partition, account, time_min, mem_gb, cpus, sbatch)
            rows = submit_study(experiment, out, options, natural=natural, overrides=override, runs=runs,
                                next_runs=next_runs, build_demos=build_demos, say=console.print)
            if not wait:
                _print_run_jobs(rows)
                return
            rows = wait_for_runs(out, study_spec(experiment, override, natural), say=console.print)
            _print_run_jobs(rows)
            failed = any(r.state == "failed" for r in rows)
        train = not slurm and not report_only and not (check_code and next_runs is None and runs is None)
        files = run_study(experiment, out, natural=natural, overrides=override, next_runs=next_runs, runs=runs,
                          train=train, build_demos=build_demos and not slurm, check_code=check_code,
                          say=console.print)
        if report_only and submitted_jobs(out.resolve()):
            _print_run_jobs(run_jobs(out.resolve(), study_spec(experiment, override, natural)))
    except errors as e:
        _fail(str(e))
    if files:
        console.print(f"wrote {files['markdown']}, {files['html']} and {files['curves']}")
    else:
        console.print(f"no finished runs in {out / 'runs'} yet: no report written")
    if slurm and failed:
        raise typer.Exit(code=1)


@app.command()
def interventions(out: Path = typer.Option(..., help="Folder for the datasets, policies and the report (e.g. "
                                           "docs/results/interventions)."),
                  experiment: str = typer.Option("interventions", help="The experiment config (its "
                                                 "`interventions:` block)."),
                  override: list[str] = typer.Option([], help="Hydra override, e.g. "
                                                     "experiment.interventions.seeds=[0,1,2] (repeatable)."),
                  report_only: bool = typer.Option(False, "--report", help="Run nothing: rebuild the report."),
                  workers: int = typer.Option(1, min=1, help="(task, seed) cells run at once, each in its own "
                                              "process (one per core).")):
    """Demos or interventions: success against frames of human effort, as whole demos or as takeovers (HG-DAgger).
    Continues an interrupted run in OUT."""
    from surrol_data.datasets.reader import DatasetError
    from surrol_data.study.interventions import run_interventions

    try:
        files = run_interventions(out, experiment, override, train=not report_only, say=console.print,
                                  workers=workers)
    except (ValueError, FileNotFoundError, DatasetError) as e:
        _fail(str(e))
    if files:
        console.print(f"wrote {files['markdown']}, {files['html']} and {files['figure']}")
    else:
        console.print(f"no results in {out} yet: no report written")


@app.command("train-bc")
def train_bc_cmd(dataset: Path = typer.Argument(..., help="Dataset folder with demos."),
                 out: Path = typer.Option(..., help="Checkpoint file to write (.pt)."),
                 epochs: int = typer.Option(20, min=1),
                 steps_per_epoch: int = typer.Option(100, min=1),
                 seed: int = typer.Option(0),
                 skill: Optional[str] = typer.Option(None, help="Only episodes of this skill (expert, novice, scripted)."),
                 successful_only: bool = typer.Option(True, help="Only successful episodes."),
                 frames: str = typer.Option("all", help="Which frames: all; human (whole demos and the takeover "
                                            "segments of intervention sessions: HG-DAgger); intervention (the "
                                            "takeover segments only)."),
                 gmm_modes: int = typer.Option(0, min=0, help="0: a deterministic actor fit by MSE; N: BC-GMM with N "
                                               "modes (robomimic's choice for people's demos, e.g. 5).")):
    """Train a behaviour-cloning policy from a dataset's demos (selected by provenance)."""
    from surrol_data.algos.bc import BCConfig, demo_arrays, train_bc
    from surrol_data.datasets.reader import DatasetError, DatasetReader

    from surrol_data.datasets.guard import require_valid

    try:
        require_valid(dataset, _note)
        reader = DatasetReader(dataset)
    except DatasetError as e:
        _fail(str(e))
    where = {}
    if skill:
        where["skill"] = skill
    if successful_only:
        where["success"] = True
    episodes = reader.select(where or None)
    if not episodes:
        _fail(f"no episodes of {dataset} match {where}; see `surrol-data info {dataset}`")
    from surrol_data.algos.demos import FRAME_SELECTIONS, select_frames

    if frames not in FRAME_SELECTIONS:
        _fail(f"--frames must be one of {', '.join(FRAME_SELECTIONS)}, got {frames!r}")
    trajectories, _ = select_frames(reader.trajectories(episodes), episodes, frames)
    if not trajectories:
        _fail(f"--frames {frames}: the {len(episodes)} selected episodes of {dataset} hold no takeover frames; "
              "record some with `surrol-data collect --source intervene ... --append`")
    obs, goal, action, episode = demo_arrays(trajectories)
    policy = train_bc(obs, goal, action, BCConfig(epochs=epochs, steps_per_epoch=steps_per_epoch, seed=seed,
                                                      gmm_modes=gmm_modes), episode_index=episode)
    console.print(f"trained on {len(episodes)} episodes ({len(obs)} samples); saved {policy.save(out)}")


@app.command(context_settings={"allow_extra_args": True, "ignore_unknown_options": True, "help_option_names": []})
def train(ctx: typer.Context):
    """Train a policy (Hydra app): `surrol-data train algo=ddpgbc task=NeedlePick demos=script seed=0`; sweeps with -m.

    Every argument goes to Hydra (overrides, -m, --cfg job, --hydra-help); configs are in the repo's configs/.
    """
    from surrol_data.train_app import main as train_main

    train_main(list(ctx.args))


@app.command()
def view(dataset: Path = typer.Argument(..., help="Dataset folder, or a Rerun recording (.rrd) to serve with --web."),
         out: Optional[Path] = typer.Option(None, help="Rerun recording to write (.rrd)."),
         episodes: str = typer.Option("0", help="Episode indices to show side by side, e.g. 0,3,5-9."),
         web: bool = typer.Option(False, help="Serve the recording in Rerun's web viewer (until Ctrl-C)."),
         web_port: Optional[int] = typer.Option(None, min=1, max=65535, help="Port of the web viewer with --web "
                                                "(default: a free one)."),
         open_browser: bool = typer.Option(True, help="With --web: open the viewer in the default browser."),
         scene: bool = typer.Option(True, help="Replay each episode to show the scene's bodies and the instruments "
                                                "as moving meshes (a few seconds per episode).")):
    """Rerun view of dataset episodes: scene and instruments, tool paths, objects, goal, actions, jaw, clutch, camera,
    provenance."""
    from surrol_data.datasets.info import read_sidecar
    from surrol_data.datasets.reader import DatasetError, DatasetReader
    from surrol_data.viz.instrument import psm_rcm_positions

    from surrol_data.datasets.guard import require_valid

    if dataset.suffix == ".rrd" and not web:
        _fail(f"{dataset} is a Rerun recording already: add --web to serve it to a browser")
    if out is None and not web:
        _fail("say where the recording goes: --out FILE.rrd, and/or --web to serve it in Rerun's web viewer")
    if web:
        from surrol_data.viz.ports import free_port, port_taken

        if web_port is not None and port_taken(web_port):
            _fail(f"--web-port {web_port} is taken (another program listens there); choose another, or leave "
                  "--web-port out to use a free one")
        web_port = web_port or free_port()
    if dataset.suffix == ".rrd":   # a recording made before (demo, report, view --out): served as it is
        if not dataset.is_file():
            _fail(f"{dataset} does not exist")
        _serve_web(None, None, web_port, open_browser, recording=dataset)
        return
    wanted = _episode_indices(episodes)
    try:
        require_valid(dataset, _note)
        reader = DatasetReader(dataset)
    except (DatasetError, ValueError) as e:
        _fail(str(e))
    table = reader.episodes.set_index("episode_index")
    missing = [e for e in wanted if e not in table.index]
    if missing:
        _fail(f"--episodes: {missing} are not in {dataset} (it has {len(table)} episodes, 0-{len(table) - 1})")
    items = []
    with _working(f"reading {len(wanted)} episode(s) of {dataset} ..."):
        for ep in wanted:
            row = table.loc[ep].to_dict()
            label = f"ep{ep} {row.get('source', '')} {row.get('skill', '')}".strip()
            items.append((label, reader.trajectory(ep, images=True),
                          {k: row[k] for k in row if not str(k).startswith("stats")}))
    rcms = psm_rcm_positions(read_sidecar(dataset).get("env_id", ""))
    unknown = [prov.get(k) for _, _, prov in items for k in ("env_id", "seed")]
    if scene and any(v is None or v != v for v in unknown):   # (v != v: a NaN from the episodes table)
        _note("episodes without env_id and seed in their provenance cannot be replayed: showing them without the scene")
        scene = False
    if out is not None:
        from surrol_data.viz.rerun_log import save_rrd

        with _working(f"writing {out} ..."):
            written = save_rrd(out, items, rcm_positions=rcms, scene=scene)
        from surrol_data.viz.open_command import recording_view_command

        console.print(f"wrote {written}; open it with: {recording_view_command(out)}", highlight=False, markup=False,
                      soft_wrap=True)  # no line break inside the command
    if web:
        _serve_web(items, rcms, web_port, open_browser, scene)


def _serve_web(items, rcms, web_port: int, open_browser: bool, scene: bool = True,
               recording: Optional[Path] = None) -> None:
    """Serve the episodes (or the ``recording``, an .rrd file) from this process: a gRPC server holds the recording,
    the web viewer reads it.

    Both listen on ports free a moment before (not Rerun's fixed 9876, where another viewer's server would hand
    this one its data); the URL is printed only once the data is in the server and the viewer's page answers."""
    import time
    from urllib.parse import quote

    import rerun as rr

    from surrol_data.viz.ports import free_port, wait_for_http
    from surrol_data.viz.rerun_log import APPLICATION_ID, log_trajectories

    rec = rr.RecordingStream(APPLICATION_ID)
    url = rec.serve_grpc(grpc_port=free_port())
    # The viewer's port is taken first (the data can take seconds per episode to replay); the browser opens and
    # the URL is printed once the data is in the server.
    rr.serve_web_viewer(web_port=web_port, open_browser=False, connect_to=url)
    if recording is not None:
        rec.log_file_from_path(recording)
    else:
        log_trajectories(rec, items, rcm_positions=rcms, scene=scene)
    rec.flush()
    if not wait_for_http(web_port):
        _fail(f"Rerun's web viewer did not answer on port {web_port}; try another --web-port")
    # The viewer's page alone connects to nothing: the address carries the data server's URL.
    page = f"http://localhost:{web_port}/?url={quote(url, safe='')}"
    if open_browser:
        import webbrowser

        webbrowser.open(page)
    console.print(f"Rerun web viewer at {page} (data from {url}); Ctrl-C stops it", highlight=False, soft_wrap=True)
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        console.print("stopped the web viewer")


@app.command()
def tasks():
    """List the registered tasks with their arms, observation, goal and action sizes and horizons."""
    import gymnasium as gym
    from rich.table import Table

    from surrol_data.envs import TASKS, env_id

    table = Table(title="surrol_data tasks", caption="gymnasium.make(\"SurRoL/<task>-v0\"); camera=True adds the "
                                                     "endoscope image to the observation")
    for col in ("task", "arms", "obs", "goal", "action", "horizon"):
        table.add_column(col)
    with _working("making each task's env ..."):
        for name in TASKS:
            env = gym.make(env_id(name))
            spaces = env.observation_space
            table.add_row(name, _arms(env), str(spaces["observation"].shape[0]),
                          str(spaces["desired_goal"].shape[0]), str(env.action_space.shape[0]),
                          str(env.spec.max_episode_steps))
            env.close()
    console.print(table)


def _arms(env) -> str:
    """Which robots a task drives: the ECM alone, or one PSM per 5-D half of the action."""
    if getattr(env.unwrapped, "psm", None) is None:
        return "ECM"
    n = env.action_space.shape[0] // 5
    return "PSM" if n == 1 else f"PSM×{n}"


# ---------------------------------------------------------------- dataset tools (validate, merge, filter, split,
# export, push): each writes a new dataset / file and keeps the per-episode provenance.

def _nan_to_null(value):
    """JSON has no NaN: a metric with no value (e.g. steps to complete when nothing succeeded) becomes null."""
    if isinstance(value, dict):
        return {k: _nan_to_null(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_nan_to_null(v) for v in value]
    if isinstance(value, float) and value != value:
        return None
    return value


def _this_command() -> str:
    return shlex.join(["surrol-data", *sys.argv[1:]])


@app.command()
def validate(dataset: Path = typer.Argument(..., help="Dataset folder."),
             reward: bool = typer.Option(True, help="Check rewards against the task's compute_reward (makes the env)."),
             lerobot: bool = typer.Option(True, help="Check that LeRobotDataset reads it (imports lerobot, ~6 s)."),
             trust: Optional[str] = typer.Option(None, help="A public key (KEY.pub, or its 64 hex digits): also check "
                                                 "that the dataset is signed by it and its seals are the ones signed.")):
    """Check schema, provenance, counts, NaN/inf, rewards and LeRobot readability; exit 1 listing each problem."""
    from surrol_data.datasets.validate import STAGES, validate_dataset

    trusted = _trusted_key(trust) if trust is not None else None
    stages = tuple(s for s in STAGES if (s != "reward" or reward) and (s != "lerobot" or lerobot))
    with _stages(f"validate {dataset}", stages) as stage:
        problems = validate_dataset(dataset, check_reward=reward, check_lerobot=lerobot, progress=stage)
    if trusted is not None and (dataset / "meta").is_dir():
        from surrol_data.datasets.signing import verify

        problems += [f"signature: {why}" for why in verify(dataset, trusted)]
    for problem in problems:
        console.print(f"[bold red]✗[/] {problem}", markup=True, highlight=False)
    if problems:
        console.print(f"{dataset}: {len(problems)} problem(s)")
        from surrol_data.datasets.guard import adopt_hint, rewritten_by_lerobot

        if rewritten_by_lerobot(dataset):
            console.print(adopt_hint(dataset), highlight=False, markup=False)
        raise typer.Exit(code=1)
    from surrol_data.datasets.validated_cache import dataset_digest, remember_valid

    remember_valid(dataset_digest(dataset))
    if trusted is not None:
        console.print(f"[green]✓[/] {dataset} is signed by the trusted key and its seals are the ones signed")   # every check passed: the commands' own check may skip these bytes
    console.print(f"[green]✓[/] {dataset} is a valid surrol_data dataset")


def _trusted_key(spec: str):
    from surrol_data.datasets.signing import load_public
    from surrol_data.extras import MissingExtra

    try:
        return load_public(spec)
    except (ValueError, MissingExtra) as e:   # DatasetError is a ValueError
        _fail(str(e))


def _sign_outputs(outputs: list[Path], key: Optional[Path]) -> None:
    """Sign what merge / filter / split wrote, when given --key (their outputs are never signed otherwise)."""
    if key is None:
        return
    from surrol_data.datasets.signing import sign
    from surrol_data.extras import MissingExtra

    for out in outputs:
        try:
            with _disk_full_is_an_error(out, _each_file_whole(out)):
                entry = sign(out, key)
        except (ValueError, MissingExtra) as e:
            _fail(f"{out} was written but not signed: {e}")
        console.print(f"signed {out} with key {entry['public_key'][:16]}…")


def _key_option():
    return typer.Option(None, "--key", help="Sign the output with this Ed25519 private key (see `surrol-data "
                                            "keygen`); without it the output is not signed.")


@app.command()
def keygen(out: Path = typer.Option(..., help="The private key file to write (its public key goes to OUT.pub).")):
    """Make an Ed25519 key pair for `sign` (private key OUT, mode 0600) and `validate --trust` (public key OUT.pub)."""
    from surrol_data.datasets.signing import generate_key
    from surrol_data.extras import MissingExtra

    try:
        private, public, hexkey = generate_key(out)
    except (FileExistsError, MissingExtra) as e:
        _fail(str(e))
    console.print(f"wrote the private key {private} (keep it secret) and the public key {public} ({hexkey}); sign "
                  f"with `surrol-data sign DATASET --key {private}`, check with `surrol-data validate DATASET "
                  f"--trust {public}`", highlight=False)


@app.command()
def sign(dataset: Path = typer.Argument(..., help="Dataset folder (sealed)."),
         key: Path = typer.Option(..., "--key", help="Ed25519 private key (PEM; `surrol-data keygen`).")):
    """Sign a dataset's seals with an Ed25519 key, so that `validate --trust PUBKEY` can tell its provenance is the
    one signed (the signer is shown by `info`)."""
    from surrol_data.datasets.guard import require_valid
    from surrol_data.datasets.reader import DatasetError
    from surrol_data.datasets.signing import sign as sign_dataset
    from surrol_data.extras import MissingExtra

    try:
        with _disk_full_is_an_error(dataset, _each_file_whole(dataset)):
            target = require_valid(dataset, _note)
            if target != dataset and target.resolve() != dataset.resolve():
                _fail(f"{dataset} cannot be written here: copy it to a writable folder and sign the copy")
            entry = sign_dataset(dataset, key)
    except (DatasetError, MissingExtra) as e:
        _fail(str(e))
    console.print(f"signed {dataset} with key {entry['public_key']} ({len(entry['manifest_sha256'])}-digit manifest "
                  f"digest {entry['manifest_sha256'][:16]}…)", highlight=False)


@app.command()
def repair(dataset: Path = typer.Argument(..., help="Dataset folder left by a killed recording, or damaged.")):
    """Keep every intact episode of a killed or damaged dataset; say what was dropped and why (files moved aside)."""
    from surrol_data.datasets.repair import repair as repair_dataset
    from surrol_data.datasets.reader import DatasetError

    try:
        with _working(f"repairing {dataset} ..."), _disk_full_is_an_error(dataset):
            report = repair_dataset(dataset)
    except DatasetError as e:
        _fail(str(e))
    for line in report.lines():
        console.print(line, highlight=False)
    from surrol_data.datasets.guard import adopt_hint, rewritten_by_lerobot

    if rewritten_by_lerobot(dataset):   # not damaged: what it lacks, adopt restores
        console.print(adopt_hint(dataset), highlight=False, markup=False)


@app.command()
def adopt(dataset: Path = typer.Argument(..., help="A dataset rewritten by lerobot's own tools (aggregate_datasets, "
                                                   "lerobot-edit-dataset)."),
          original: list[Path] = typer.Option(..., "--from", help="The surrol_data dataset it was made from; "
                                              "repeat for an aggregate of several (--from A --from B).")):
    """Restore provenance, seals, device traces, sidecar and card of a dataset lerobot's tools rewrote, matching
    each episode to the original's by the content hash of its frames."""
    from surrol_data.datasets.adopt import adopt as adopt_dataset
    from surrol_data.datasets.reader import DatasetError

    try:
        with _working(f"adopting {dataset} ..."), _disk_full_is_an_error(dataset, _each_file_whole(dataset)):
            report = adopt_dataset(dataset, original)
    except DatasetError as e:
        _fail(str(e))
    for line in report.lines():
        console.print(line, highlight=False)


@app.command()
def merge(datasets: list[Path] = typer.Argument(..., help="Input dataset folders (same task, fps and features)."),
          out: Optional[Path] = typer.Option(None, help="New dataset folder for the merged episodes."),
          drop_duplicates: bool = typer.Option(False, help="Keep one copy of episodes with equal content instead "
                                                           "of refusing the merge (writes the episodes again)."),
          key: Optional[Path] = _key_option()):
    """Merge datasets into a new one with lerobot's aggregate_datasets (episodes renumbered; provenance, device
    traces and videos kept as they are; duplicate episodes refused)."""
    from surrol_data.datasets.merge import merge_datasets
    from surrol_data.datasets.reader import DatasetError

    if out is None:
        first = datasets[0]
        if len(datasets) >= 2 and not (first / "meta" / "info.json").exists():
            # The earlier grammar `merge OUT IN...`: still understood, for a while.
            _note(f"`merge OUT IN...` is deprecated: write `surrol-data merge {' '.join(map(str, datasets[1:]))} "
                  f"--out {first}`")
            out, datasets = first, datasets[1:]
        else:
            _fail("say where the merged dataset goes: surrol-data merge IN... --out OUT")
    try:
        with _disk_full_is_an_error(out, _inputs_unchanged(out)):
            merge_datasets(out, datasets, command=_this_command(), drop_duplicates=drop_duplicates)
    except (DatasetError, ValueError, FileExistsError) as e:
        _fail(str(e))
    console.print(f"merged {len(datasets)} dataset(s) into {out}")
    _sign_outputs([out], key)


@app.command("filter")
def filter_cmd(dataset: Path = typer.Argument(..., help="Dataset folder."),
               out: Path = typer.Option(..., help="New dataset folder."),
               where: Optional[str] = typer.Option(None, help="Expression over provenance, e.g. "
                                                               "'skill == \"expert\" and success'."),
               episodes: Optional[str] = typer.Option(None, help="Episode indices, e.g. 0,3,5-9 (with --where: "
                                                                 "those of them that match)."),
               key: Optional[Path] = _key_option()):
    """Copy the episodes matching --where and/or listed by --episodes into a new dataset (provenance kept)."""
    from surrol_data.datasets.merge import filter_dataset
    from surrol_data.datasets.reader import DatasetError

    if where is None and episodes is None:
        _fail("say which episodes to keep: --where EXPRESSION and/or --episodes 0,3,5-9")
    indices = _episode_indices(episodes)
    try:
        with _disk_full_is_an_error(out, _inputs_unchanged(out)):
            filter_dataset(dataset, out, where, command=_this_command(), episodes=indices)
    except (DatasetError, ValueError, FileExistsError) as e:
        _fail(str(e))
    said = " and ".join(x for x in (f"where {where}" if where else "", f"--episodes {episodes}" if episodes else "")
                        if x)
    console.print(f"wrote the episodes {said} to {out}")
    _sign_outputs([out], key)


@app.command()
def split(dataset: Path = typer.Argument(..., help="Dataset folder."),
          out: Path = typer.Option(..., help="Folder for the two new datasets OUT/train and OUT/valid."),
          valid_fraction: float = typer.Option(0.1, help="Fraction of each (source, skill, operator) group for valid."),
          seed: int = typer.Option(0, help="Seed of the shuffle."),
          where: Optional[str] = typer.Option(None, help="Only episodes matching this expression."),
          key: Optional[Path] = _key_option()):
    """Split into train and valid datasets, stratified by source, skill and operator."""
    from surrol_data.datasets.merge import split_dataset
    from surrol_data.datasets.reader import DatasetError

    try:
        with _disk_full_is_an_error(out, _split_kept(out)):
            parts = split_dataset(dataset, out, valid_fraction, seed, where=where, command=_this_command())
    except (DatasetError, ValueError, FileExistsError) as e:
        _fail(str(e))
    console.print(f"wrote {parts['train']} and {parts['valid']}")
    _sign_outputs([parts["train"], parts["valid"]], key)


class ExportFormat(str, Enum):
    robomimic = "robomimic"
    minari = "minari"


def _cameras(dataset: Path) -> list[str]:
    """The camera names of a dataset, from its info.json alone (the dataset may be one read through a repaired
    view: its own files are not all readable)."""
    from surrol_data.datasets.reader import load_info
    from surrol_data.datasets.readonly_view import view_of

    return [k.removeprefix("observation.images.") for k, ft in load_info(view_of(dataset) or dataset)["features"].items()
            if ft["dtype"] == "video" and k.startswith("observation.images.")]


@app.command()
def export(dataset: Path = typer.Argument(..., help="Dataset folder."),
           format: ExportFormat = typer.Option(..., "--format", help="robomimic (one .hdf5) or minari (a folder)."),
           out: Path = typer.Option(..., help="robomimic: FILE.hdf5; minari: the datasets root folder."),
           where: Optional[str] = typer.Option(None, help="Only episodes matching this expression."),
           episodes: Optional[str] = typer.Option(None, help="Only these episode indices, e.g. 0,3,5-9."),
           dataset_id: Optional[str] = typer.Option(None, help="minari: dataset id (default surrol/<task>/<name>-v0)."),
           valid_fraction: float = typer.Option(0.1, help="robomimic: fraction in mask/valid."),
           seed: int = typer.Option(0, help="robomimic: seed of the train/valid split."),
           overwrite: bool = typer.Option(False, help="robomimic: replace an existing file.")):
    """Export to robomimic HDF5 (with filter keys by skill/operator and train/valid) or to Minari."""
    from surrol_data.datasets.reader import DatasetError

    indices = _episode_indices(episodes)
    try:
        with _disk_full_is_an_error(out, _export_kept(out, dataset)):
            if format is ExportFormat.robomimic:
                from surrol_data.datasets.export_robomimic import export_robomimic

                path = export_robomimic(dataset, out, where=where, valid_fraction=valid_fraction, seed=seed,
                                        overwrite=overwrite, episodes=indices)
                cameras = _cameras(dataset)
                console.print(f"wrote {path}" + (f" (camera frames in obs/{cameras[0]}_image)" if cameras else ""))
            else:
                from surrol_data.datasets.export_minari import export_minari

                ds = export_minari(dataset, out, dataset_id=dataset_id, where=where, episodes=indices)
                console.print(f"wrote Minari dataset {ds.spec.dataset_id!r} ({ds.total_episodes} episodes) under {out}; "
                              f"load it with MINARI_DATASETS_PATH={out} and minari.load_dataset({ds.spec.dataset_id!r})")
                if _cameras(dataset):
                    _note("the Minari export holds the state, goals, actions and rewards, not the camera frames; "
                          "`--format robomimic` exports those too (obs/<camera>_image)")
    except (DatasetError, ValueError, FileExistsError, ImportError) as e:
        _fail(str(e))


@app.command()
def push(dataset: Path = typer.Argument(..., help="Dataset folder."),
         repo_id: str = typer.Option(..., help="Hub dataset repo, e.g. my-lab/needle-pick-demos."),
         private: bool = typer.Option(False, help="Create the repo private."),
         dry_run: bool = typer.Option(False, help="Only list what would be uploaded (no network)."),
         skip_validation: bool = typer.Option(False, help="Push even if `validate` finds problems.")):
    """Upload a dataset to the Hugging Face Hub (validates first; needs HF_HUB_OFFLINE=0 and a token)."""
    from surrol_data.datasets.push import push_dataset
    from surrol_data.datasets.reader import DatasetError

    try:
        with _working(f"{'planning' if dry_run else 'validating and uploading'} {dataset} ..."):
            plan = push_dataset(dataset, repo_id, private=private, dry_run=dry_run, skip_validation=skip_validation)
    except (DatasetError, ValueError, RuntimeError) as e:
        _fail(str(e))
    for name in plan.files:
        console.print(f"  {name}", highlight=False)
    verb = "would upload" if dry_run else "uploaded"
    console.print(f"{verb} {len(plan.files)} files ({plan.bytes / 1e6:.2f} MB) to datasets/{repo_id}"
                  + (f", tag {plan.revision_tag}" if plan.revision_tag else ""))


@app.command()
def upgrade(dataset: Path = typer.Argument(..., help="Dataset folder written by an earlier surrol_data schema."),
            keep_backup: bool = typer.Option(False, help="Keep the original beside it as DATASET.schema1.")):
    """Rewrite a dataset in the current schema (environment state, next.truncated, named dimensions)."""
    from surrol_data.datasets.reader import DatasetError
    from surrol_data.datasets.upgrade import upgrade_dataset

    try:
        with console.status(f"upgrading {dataset}"), _disk_full_is_an_error(dataset, _upgrade_kept(dataset)):
            report = upgrade_dataset(dataset, keep_backup=keep_backup)
    except DatasetError as e:
        _fail(str(e))
    for line in report.lines():
        console.print(line, highlight=False)


if __name__ == "__main__":
    app()
