"""Which code a training run came from, and whether two runs' code means the same.

A run records its :class:`CodeIdentity`: the commit, whether the code paths (``surrol_data/``, ``configs/``) had
uncommitted changes, the CPU, and two fingerprints measured on that CPU (plus a hash of the training config) just before training — the env's
(:func:`surrol_data.envs.fingerprint.env_fingerprint`) and the learner's
(:func:`surrol_data.algos.fingerprint.learner_fingerprint`). Floating-point bits differ between CPUs, so
fingerprints compare only on one CPU. Two identities mean the same code when

* they ran on the same CPU with equal fingerprints, or
* they ran the same commit with no uncommitted code changes, or
* a chain of those links them (a study's ``code_checks.jsonl`` adds links: the fingerprints of one commit
  measured on another machine, i.e. a before/after check there),

and never when they ran on the same CPU with different fingerprints: that is a change in behaviour, whatever
the commits say. :func:`check_same_code` applies the rule and names the runs that break it.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path


class CodeIdentityError(ValueError):
    """Runs whose code differs in meaning, or cannot be shown to mean the same: what differs and what to do."""


@dataclass(frozen=True)
class CodeIdentity:
    commit: str
    dirty: bool                 # uncommitted changes under surrol_data/ or configs/ when it was measured
    cpu: str
    env_fingerprint: str
    learner_fingerprint: str
    config_fingerprint: str     # the run's training config less seed, demos and folder (no CPU dependence)

    @property
    def fingerprints(self) -> tuple[str, str, str]:
        return self.cpu, self.env_fingerprint, self.learner_fingerprint

    def as_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> CodeIdentity:
        return cls(**{k: d[k] for k in cls.__dataclass_fields__})

    def short(self) -> str:
        return (f"commit {self.commit[:10]}{' (+ uncommitted changes)' if self.dirty else ''} on {self.cpu!r}: env "
                f"{self.env_fingerprint[:12]}, learner {self.learner_fingerprint[:12]}")


def read_checks(path: Path) -> list[CodeIdentity]:
    """The identities recorded in a study's ``code_checks.jsonl`` (missing file: none)."""
    if not path.is_file():
        return []
    return [CodeIdentity.from_dict(json.loads(line)) for line in path.read_text().splitlines() if line.strip()]


def append_check(path: Path, identity: CodeIdentity) -> None:
    if identity not in read_checks(path):
        with open(path, "a") as f:
            f.write(json.dumps(identity.as_dict()) + "\n")


def check_same_code(identities: dict[str, CodeIdentity], checks: list[CodeIdentity] = ()) -> None:
    """Raise :class:`CodeIdentityError` unless every labelled identity means the same code (see the module)."""
    items = list(identities.items())
    # 0. the training config (schedule, learner parameters) is the same on every CPU
    for label, ident in items[1:]:
        if ident.config_fingerprint != items[0][1].config_fingerprint:
            raise CodeIdentityError(
                f"{label} was trained with another training config than {items[0][0]} (config fingerprint "
                f"{ident.config_fingerprint[:12]} vs {items[0][1].config_fingerprint[:12]}): the study's configs or "
                "its overrides changed. Compare their config.yaml; such runs cannot share one table.")
    # 1. same CPU, different fingerprints: a change of behaviour
    by_cpu: dict[str, tuple[str, CodeIdentity]] = {}
    for label, ident in items:
        seen = by_cpu.setdefault(ident.cpu, (label, ident))
        if seen[1].fingerprints != ident.fingerprints:
            raise CodeIdentityError(
                f"{label} and {seen[0]} were trained by code that behaves differently on the same CPU "
                f"({ident.short()} vs {seen[1].short()}): a change to the envs, the learner or the study's "
                "configs altered what they compute. Such runs cannot share one table: revert the change (and check "
                "with `surrol-data study ... --check-code`), or retrain the runs of one side into another --out.")
    # 2. connected through equal fingerprints or equal clean commits
    parent: dict[tuple, tuple] = {}

    def find(x):
        parent.setdefault(x, x)
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    def nodes(ident: CodeIdentity) -> list[tuple]:
        out = [("fingerprints", *ident.fingerprints)]
        if not ident.dirty:
            out.append(("commit", ident.commit))
        return out

    for ident in [*(i for _, i in items), *checks]:
        first, *rest = nodes(ident)
        for other in rest:
            parent[find(other)] = find(first)
    if not items:
        return
    root_label, root = items[0]
    for label, ident in items[1:]:
        if find(nodes(ident)[0]) != find(nodes(root)[0]):
            raise CodeIdentityError(
                f"{label} ({ident.short()}) cannot be shown to run the same code as {root_label} ({root.short()}): "
                "they ran on different CPUs (whose floating-point bits may differ) at different or uncommitted code. "
                f"On {ident.cpu!r}, check out commit {root.commit[:10]} and run `surrol-data study ... --check-code`, "
                "then again at the newer commit: equal fingerprints there link the two.")
