"""Signed provenance (surrol_data.datasets.signing): an untouched signed dataset passes ``validate --trust``; an
episode whose provenance was edited and re-sealed, dropped seals, a missing signature or another signer fail it;
``info`` names the signer; merge/filter/split sign their output only with ``--key``; appending drops the signature."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from typer.testing import CliRunner

from surrol_data.cli import app
from surrol_data.collect import corruptions
from surrol_data.datasets.schema import PROVENANCE_COLUMNS, PROVENANCE_PREFIX, PROVENANCE_SEAL, provenance_seal

from dataset_forgery import drop_seals

runner = CliRunner()


def _run(*args: str):
    result = runner.invoke(app, list(args))
    assert result.exception is None or isinstance(result.exception, SystemExit), result.output
    return result.exit_code, " ".join(result.output.replace("│", " ").split())


@pytest.fixture(scope="module")
def keys(tmp_path_factory) -> dict:
    folder = tmp_path_factory.mktemp("keys")
    out = {}
    for name in ("ours", "theirs"):
        code, said = _run("keygen", "--out", str(folder / name))
        assert code == 0, said
        out[name] = folder / name
        out[name + ".pub"] = folder / f"{name}.pub"
    assert (folder / "ours").stat().st_mode & 0o777 == 0o600
    return out


@pytest.fixture(scope="module")
def base(tmp_path_factory) -> Path:
    return corruptions.base_dataset(tmp_path_factory.mktemp("signing") / "base", camera=False)


@pytest.fixture
def signed(base, keys, tmp_path) -> Path:
    root = tmp_path / "signed"
    shutil.copytree(base, root)
    code, said = _run("sign", str(root), "--key", str(keys["ours"]))
    assert code == 0 and "signed" in said, said
    return root


def _validate(root: Path, key: Path) -> tuple[int, str]:
    return _run("validate", str(root), "--no-reward", "--no-lerobot", "--trust", str(key))


def test_an_untouched_signed_dataset_passes_and_info_names_the_signer(signed, keys):
    code, said = _validate(signed, keys["ours.pub"])
    assert code == 0 and "signed by the trusted key" in said, said
    public = json.loads((signed / "meta" / "surrol_data.json").read_text())["signature"]["public_key"]
    code, said = _run("info", str(signed))
    assert code == 0 and "signed by" in said and public[:16] in said, said


def _forge_operator(root: Path) -> None:
    """What a forger with write access does: edit a provenance value nothing else holds and recompute its (unkeyed) seal."""
    path = sorted((root / "meta" / "episodes").rglob("*.parquet"))[0]
    table = pq.read_table(path)
    rows = table.to_pylist()
    rows[0][PROVENANCE_PREFIX + "command"] = "surrol-data collect --forged"
    rows[0][PROVENANCE_SEAL] = provenance_seal({k: rows[0][PROVENANCE_PREFIX + k] for k in PROVENANCE_COLUMNS})
    pq.write_table(pa.Table.from_pylist(rows, schema=table.schema), path)


def test_a_recomputed_seal_fails_against_the_trusted_key(signed, keys):
    _forge_operator(signed)
    code, said = _run("validate", str(signed), "--no-reward", "--no-lerobot")
    assert code == 0, said   # the unkeyed seals cannot tell: that is what the signature is for
    code, said = _validate(signed, keys["ours.pub"])
    assert code == 1 and "signature: its seals are not the ones signed" in said, said


def test_dropped_seals_fail_against_the_trusted_key(signed, keys):
    drop_seals(signed)
    code, said = _validate(signed, keys["ours.pub"])
    assert code == 1 and "signature:" in said, said


def test_no_signature_or_another_signer_fails(base, signed, keys, tmp_path):
    code, said = _validate(base, keys["ours.pub"])
    assert code == 1 and "signature: it is not signed" in said, said
    code, said = _validate(signed, keys["theirs.pub"])
    assert code == 1 and "not by the trusted key" in said, said


def test_derived_datasets_are_signed_only_with_a_key(signed, keys, tmp_path):
    code, said = _run("filter", str(signed), "--where", "seed >= 1", "--out", str(tmp_path / "plain"))
    assert code == 0, said
    assert "signature" not in json.loads((tmp_path / "plain" / "meta" / "surrol_data.json").read_text())
    code, said = _run("filter", str(signed), "--where", "seed >= 1", "--out", str(tmp_path / "resigned"), "--key",
                      str(keys["theirs"]))
    assert code == 0 and "signed" in said, said
    code, said = _validate(tmp_path / "resigned", keys["theirs.pub"])
    assert code == 0, said
    code, said = _run("merge", str(signed), "--out", str(tmp_path / "unsigned"))
    assert code == 0
    assert "signature" not in json.loads((tmp_path / "unsigned" / "meta" / "surrol_data.json").read_text())
