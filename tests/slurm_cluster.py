"""A real single-node SLURM cluster for the tests: munged, slurmctld and slurmd on this machine.

    with SlurmCluster(tmp_path) as cluster:       # writes its own slurm.conf, starts the daemons, waits for `idle`
        subprocess.run(["sbatch", ...], env=cluster.env)

Everything lives in one folder (config, munge key and socket, state, spool, logs); nothing under /etc is read or
written, so it runs beside (and never touches) a system SLURM. The daemons run in the foreground as children of
this process and are stopped by their pids. The config avoids cgroups (``proctrack/linuxproc``, ``task/none``),
which a container usually lacks, and has no accounting database: job states come from slurmctld itself, which
keeps finished jobs for ``MinJobAge`` seconds.

Needs Debian's ``slurm-wlm`` and ``munge`` (``apt-get install slurm-wlm munge``); :func:`missing` names what is
absent so that tests can skip with it. ``python tests/slurm_cluster.py`` starts one and keeps it up until Ctrl-C
(``SLURM_CONF`` printed), for trying things by hand.
"""

from __future__ import annotations

import os
import secrets
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from pathlib import Path

BINARIES = {"slurmctld": "slurm-wlm", "slurmd": "slurm-wlm", "sbatch": "slurm-wlm", "sinfo": "slurm-wlm",
            "scontrol": "slurm-wlm", "munged": "munge"}
PARTITION = "debug"


def missing() -> str | None:
    """Why a cluster cannot be started here (the Debian packages to install), or None."""
    absent = sorted({pkg for exe, pkg in BINARIES.items() if shutil.which(exe) is None
                     and not Path("/usr/sbin", exe).exists()})
    if absent:
        return f"needs a local SLURM: apt-get install {' '.join(absent)} (Debian packages)"
    if os.geteuid() != 0:
        return "needs root to run slurmd (it starts every job as the submitting user)"
    return None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _own_session_dying_with_parent() -> None:
    """In the daemon before it starts: its own session (a Ctrl-C at the terminal is the test's, not the daemon's),
    and SIGTERM when the process that started it dies, so that a killed test run leaves no daemon behind."""
    import ctypes

    os.setsid()
    ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGTERM)   # PR_SET_PDEATHSIG


def _exe(name: str) -> str:
    return shutil.which(name) or str(Path("/usr/sbin", name))


class SlurmCluster:
    """One node (this host, ``cpus`` CPUs, ``memory_mb`` of memory) in one partition, ``debug``."""

    def __init__(self, root: Path | None = None, cpus: int = 2, memory_mb: int = 4000):
        self.root = Path(root or tempfile.mkdtemp(prefix="surrol_slurm_"))
        self.cpus, self.memory_mb = cpus, memory_mb
        self.node = socket.gethostname()
        self.conf = self.root / "slurm.conf"
        self._procs: dict[str, subprocess.Popen] = {}

    @property
    def env(self) -> dict[str, str]:
        """This process's environment with the client commands (sbatch, sinfo, ...) pointed at this cluster."""
        return {**os.environ, "SLURM_CONF": str(self.conf)}

    def _write_config(self) -> None:
        r = self.root
        for sub in ("state", "spool", "log", "munge"):
            (r / sub).mkdir(parents=True, exist_ok=True, mode=0o700)
        key = r / "munge" / "munge.key"
        key.write_bytes(secrets.token_bytes(1024))
        key.chmod(0o600)
        self.conf.write_text(f"""\
ClusterName=surroltest
SlurmctldHost={self.node}(127.0.0.1)
SlurmctldPort={_free_port()}
SlurmdPort={_free_port()}
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket={r}/munge/munge.socket
CredType=cred/munge
StateSaveLocation={r}/state
SlurmdSpoolDir={r}/spool
SlurmctldPidFile={r}/slurmctld.pid
SlurmdPidFile={r}/slurmd.pid
SlurmctldLogFile={r}/log/slurmctld.log
SlurmdLogFile={r}/log/slurmd.log
SlurmctldDebug=info
SlurmdDebug=info
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/filetxt
JobCompLoc={r}/log/jobcomp.txt
SchedulerType=sched/backfill
SelectType=select/cons_tres
SelectTypeParameters=CR_CPU_Memory
MpiDefault=none
ReturnToService=2
MinJobAge=600
KillWait=5
InactiveLimit=0
SlurmctldTimeout=30
SlurmdTimeout=30
NodeName={self.node} NodeAddr=127.0.0.1 CPUs={self.cpus} RealMemory={self.memory_mb} State=UNKNOWN
PartitionName={PARTITION} Nodes={self.node} Default=YES MaxTime=INFINITE State=UP
""")

    def _start(self, name: str, argv: list[str]) -> None:
        log = open(self.root / "log" / f"{name}.out", "ab")
        self._procs[name] = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, env=self.env,
                                             preexec_fn=_own_session_dying_with_parent)
        log.close()

    def start(self, timeout: float = 60) -> SlurmCluster:
        reason = missing()
        if reason:
            raise RuntimeError(reason)
        self._write_config()
        m = self.root / "munge"
        self._start("munged", [_exe("munged"), "--foreground", "--force", f"--key-file={m}/munge.key",
                               f"--socket={m}/munge.socket", f"--pid-file={m}/munged.pid",
                               f"--log-file={m}/munged.log", f"--seed-file={m}/munged.seed"])
        self._wait(lambda: (m / "munge.socket").exists(), timeout, "munged")
        self._start("slurmctld", [_exe("slurmctld"), "-D", "-i", "-f", str(self.conf)])
        self._start("slurmd", [_exe("slurmd"), "-D", "-f", str(self.conf), "-N", self.node])
        self._wait(self._node_idle, timeout, "the node to be idle in sinfo")
        return self

    def _node_idle(self) -> bool:
        out = subprocess.run(["sinfo", "-h", "-N", "-o", "%T"], env=self.env, capture_output=True, text=True)
        return out.returncode == 0 and out.stdout.strip() == "idle"

    def _wait(self, ready, timeout: float, what: str) -> None:
        deadline = time.monotonic() + timeout
        while not ready():
            dead = [n for n, p in self._procs.items() if p.poll() is not None]
            if dead or time.monotonic() > deadline:
                self.stop()
                raise RuntimeError(f"local SLURM: gave up waiting for {what} "
                                   f"({'exited: ' + ', '.join(dead) if dead else f'{timeout:.0f} s'}); "
                                   f"logs in {self.root / 'log'}:\n{self.logs()}")
            time.sleep(0.5)

    def logs(self) -> str:
        """The tail of every daemon log (what a failed start or a stuck job shows)."""
        parts = []
        for path in sorted((self.root / "log").glob("*")) + [self.root / "munge" / "munged.log"]:
            if path.is_file():
                parts.append(f"--- {path.name}\n" + "\n".join(path.read_text(errors="replace").splitlines()[-30:]))
        return "\n".join(parts)

    def squeue(self) -> str:
        return subprocess.run(["squeue", "-h", "-o", "%i %T %j"], env=self.env, capture_output=True,
                              text=True).stdout

    def requeue(self, job_id: str, timeout: float = 120) -> None:
        """``scontrol requeue`` the job, then make it eligible at once: SLURM holds a requeued job back for about
        two minutes (its BeginTime), which would only slow the test down."""
        subprocess.run(["scontrol", "requeue", job_id], env=self.env, check=True, capture_output=True)
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            state = subprocess.run(["squeue", "-h", "-j", job_id, "-o", "%T"], env=self.env, capture_output=True,
                                   text=True).stdout.strip()
            if state == "PENDING" and subprocess.run(["scontrol", "update", f"JobId={job_id}", "StartTime=now"],
                                                     env=self.env, capture_output=True).returncode == 0:
                return
            time.sleep(0.5)
        raise RuntimeError(f"local SLURM: job {job_id} did not go back to pending after `scontrol requeue`")

    def wait_empty(self, timeout: float = 600) -> None:
        """Until no job is pending or running."""
        self._wait(lambda: not self.squeue().strip(), timeout, "the queue to empty")

    def stop(self) -> None:
        # jobs first (their processes belong to slurmstepd), then the daemons in reverse order of start
        if "slurmctld" in self._procs and self._procs["slurmctld"].poll() is None:
            subprocess.run(["scancel", "--full", f"--partition={PARTITION}"], env=self.env, capture_output=True)
        for name in ("slurmd", "slurmctld", "munged"):
            proc = self._procs.pop(name, None)
            if proc is None or proc.poll() is not None:
                continue
            proc.send_signal(signal.SIGTERM)
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()

    def __enter__(self) -> SlurmCluster:
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()


def _interrupt(signum, frame):
    raise KeyboardInterrupt


if __name__ == "__main__":
    signal.signal(signal.SIGTERM, _interrupt)   # `kill PID` stops the daemons too (a background job ignores SIGINT)
    signal.signal(signal.SIGINT, _interrupt)
    with SlurmCluster() as c:
        print(f"SLURM up: export SLURM_CONF={c.conf}   (Ctrl-C or kill {os.getpid()} stops it)", flush=True)
        try:
            signal.pause()
        except KeyboardInterrupt:
            pass
