"""The params each dvc.yaml stage depends on, as DVC itself reads them (foreach expanded):
they exist in params.yaml, and `dvc exp run -S degrade.threshold_sigma=...` (the command
users run most) reaches only the stages whose result can change (issue 13)."""
from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest
import yaml

from rdnet.sim.settings import DegradeConfig

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def stages():
    """{stage name: (cmd, [param keys])} from DVC's own parser of dvc.yaml."""
    repo_mod = pytest.importorskip("dvc.repo")
    from dvc.dependency.param import ParamsDependency
    with repo_mod.Repo(str(ROOT)) as repo:
        return {st.addressing: (st.cmd, [k for d in st.deps if isinstance(d, ParamsDependency)
                                         for k in (d.params or [])])
                for st in repo.index.stages}


def covers(key: str, target: str) -> bool:
    """Whether depending on ``key`` means depending on ``target`` (a section covers its keys)."""
    return target == key or target.startswith(key + ".")


def test_every_stage_param_exists_in_params_yaml(stages):
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    assert len(stages) > 20
    for name, (_, keys) in stages.items():
        for key in keys:
            node = params
            for part in key.split("."):
                assert isinstance(node, dict) and part in node, f"{name}: {key} is not in params.yaml"
                node = node[part]


def test_calibrate_real_depends_on_every_degrade_key_it_does_not_set(stages):
    """calibrate_real sets the degrade effects on its command line (the ideal base); the
    degrade keys it leaves to params.yaml, and only those, are its params."""
    cmd, keys = stages["calibrate_real"]
    on_cmd = set(re.findall(r"--set degrade\.(\w+)=", cmd))
    deps = {k.split(".", 1)[1] for k in keys if k.startswith("degrade.")}
    assert "degrade" not in keys and "threshold_sigma" in on_cmd
    assert not on_cmd & deps
    assert on_cmd | deps == {f.name for f in dataclasses.fields(DegradeConfig)}
    assert {"sensor", "calibrate", "interpolate"} <= set(keys)   # all read by `rdnet calibrate`


def test_threshold_sigma_reruns_only_the_simulating_stages(stages):
    direct = {name for name, (_, keys) in stages.items()
              if any(covers(k, "degrade.threshold_sigma") for k in keys)}
    assert direct == {"simulate", "stress"}
    # and the trainings do not hang on the stress/evaluation keys of `study`
    for name, (_, keys) in stages.items():
        if name.startswith("train_"):
            assert not any(covers(k, "study.stress_scales") for k in keys), name
