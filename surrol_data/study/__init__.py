"""The demo-source study (the paper's Table I), run by run.

    surrol-data study table1 --out docs/results/table1 --next 2          # train the next 2 pending runs, report
    surrol-data study table1 --out docs/results/table1 --runs expert/0   # or name them
    surrol-data study table1 --out docs/results/table1 --report          # the report from the finished runs

The experiment config (``configs/experiment/<name>.yaml``) holds the training schedule and, under ``study:``, what
the study needs besides (:class:`~surrol_data.study.spec.StudySpec`). Its parts:

* :mod:`~surrol_data.study.spec`: the spec and the fixed order of the runs (seeds outermost);
* :mod:`~surrol_data.study.demo_sets`: the demo sets, shipped under ``datasets/`` with their hashes;
* :mod:`~surrol_data.study.identity`: the code identity each run records;
* :mod:`~surrol_data.study.runs`: training the selected runs, their final folders, the report;
* :mod:`~surrol_data.study.cluster`: the same runs as SLURM jobs, one per run (``--launcher slurm``).
"""

from surrol_data.study.demo_sets import build_demo_sets, demo_quality, demo_quality_markdown
from surrol_data.study.runs import run_study
from surrol_data.study.spec import StudySpec, load_spec

__all__ = ["StudySpec", "build_demo_sets", "demo_quality", "demo_quality_markdown", "load_spec", "run_study"]
