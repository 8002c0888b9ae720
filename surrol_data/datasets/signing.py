"""Signed provenance, opt-in: an Ed25519 signature over a dataset's seals (``surrol-data sign``, ``validate --trust``).

The seals (:mod:`surrol_data.datasets.seals`) are unkeyed hashes: they catch an accident (a provenance value edited
by hand, a swapped video), not a forger with write access, who recomputes the seal of what he edited or drops the
seals altogether. A signature closes that: :func:`sign` signs, with a private key the forger does not hold, the
**manifest** of the dataset — its task and env id, and for every episode in order its seals (``seal/provenance``,
which covers every provenance column, the frames' ``content_hash`` included, and ``seal/<video>`` of each camera)
— and stores the signature and the public key in the sidecar (``meta/surrol_data.json``, ``"signature"``).
:func:`verify` recomputes the manifest from the dataset as it is and checks the signature against a key the user
trusts: an edited and re-sealed episode, a dropped seal, a dropped, added or reordered episode, or a signature made
with another key all fail; an untouched signed dataset passes. What the seals themselves do not cover (the frames
against ``content_hash``, the videos against their seals) is what ``validate`` checks anyway.

Keys: ``surrol-data keygen --out KEY`` (``KEY``: the PKCS#8 private key, mode 0600; ``KEY.pub``: the public key,
PEM), or OpenSSL's ``openssl genpkey -algorithm ed25519 -out KEY`` and ``openssl pkey -in KEY -pubout -out
KEY.pub``. The cryptography is the ``cryptography`` package's (the ``sign`` extra), nothing hand-rolled.

A command that changes the episodes (``collect --append``, ``repair``, ``upgrade``) drops the signature (it no
longer covers them); ``merge``/``filter``/``split`` sign their output only when given ``--key``.
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

import pyarrow as pa

from surrol_data.datasets.errors import DatasetError

SIGNATURE = "signature"          # the sidecar entry
_FORMAT = "surrol_data-signed-seals-1"


def _crypto():
    from surrol_data.extras import require

    require("cryptography")
    from cryptography.hazmat.primitives import serialization
    from cryptography.hazmat.primitives.asymmetric import ed25519

    return serialization, ed25519


def manifest(root: str | Path) -> dict:
    """What a signature covers (see the module doc), read from ``root``'s metadata."""
    from surrol_data.datasets.info import read_sidecar
    from surrol_data.datasets.reader import EPISODES_DIR, episode_rows, parquet_files
    from surrol_data.datasets.schema import SEAL_PREFIX

    root = Path(root)
    tables = [episode_rows(p) for p in parquet_files(root, EPISODES_DIR)]
    meta = pa.concat_tables(tables, promote_options="default").sort_by("episode_index") if tables else None
    seal_columns = sorted(c for c in (meta.column_names if meta is not None else []) if c.startswith(SEAL_PREFIX))
    rows = meta.select(seal_columns).to_pylist() if meta is not None and seal_columns else []
    side = read_sidecar(root)
    return {"format": _FORMAT, "task": side.get("task"), "env_id": side.get("env_id"),
            "seal_columns": seal_columns, "episodes": [[row[c] for c in seal_columns] for row in rows]}


def manifest_digest(root: str | Path) -> str:
    return hashlib.sha256(json.dumps(manifest(root), sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def _message(digest: str) -> bytes:
    return f"{_FORMAT}:{digest}".encode()


def generate_key(out: str | Path) -> tuple[Path, Path, str]:
    """A new Ed25519 key pair: ``out`` (private, PKCS#8 PEM, mode 0600) and ``out.pub`` (public, PEM); (private path,
    public path, public key in hex). Refuses to overwrite."""
    serialization, ed25519 = _crypto()
    out = Path(out)
    public = out.with_name(out.name + ".pub")
    for path in (out, public):
        if path.exists():
            raise FileExistsError(f"{path} already exists: choose another name (a key is never overwritten)")
    key = ed25519.Ed25519PrivateKey.generate()
    private_pem = key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                    serialization.NoEncryption())
    fd = os.open(out, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as fh:
        fh.write(private_pem)
    public.write_bytes(key.public_key().public_bytes(serialization.Encoding.PEM,
                                                     serialization.PublicFormat.SubjectPublicKeyInfo))
    return out, public, _public_hex(key.public_key())


def _public_hex(public_key) -> str:
    serialization, _ = _crypto()
    return public_key.public_bytes(serialization.Encoding.Raw, serialization.PublicFormat.Raw).hex()


def _load_private(path: str | Path):
    serialization, ed25519 = _crypto()
    try:
        key = serialization.load_pem_private_key(Path(path).read_bytes(), password=None)
    except (OSError, ValueError, TypeError) as e:
        raise DatasetError(f"{path}: not an unencrypted Ed25519 private key in PEM ({e}); make one with "
                           "`surrol-data keygen --out KEY`") from None
    if not isinstance(key, ed25519.Ed25519PrivateKey):
        raise DatasetError(f"{path} is a {type(key).__name__}, not an Ed25519 key; make one with `surrol-data keygen`")
    return key


def load_public(spec: str | Path):
    """A trusted public key: a PEM file (``KEY.pub``, or OpenSSL's ``-pubout``), or 64 hex digits."""
    serialization, ed25519 = _crypto()
    text = str(spec)
    try:
        if len(text) == 64 and all(c in "0123456789abcdefABCDEF" for c in text):
            return ed25519.Ed25519PublicKey.from_public_bytes(bytes.fromhex(text))
        key = serialization.load_pem_public_key(Path(spec).read_bytes())
    except (OSError, ValueError, TypeError) as e:
        raise DatasetError(f"{spec}: not an Ed25519 public key (a PEM file such as KEY.pub, or 64 hex digits): "
                           f"{e}") from None
    if not isinstance(key, ed25519.Ed25519PublicKey):
        raise DatasetError(f"{spec} is a {type(key).__name__}, not an Ed25519 public key")
    return key


def signature_entry(root: str | Path, key_path: str | Path) -> dict:
    """The sidecar's ``"signature"`` entry for ``root`` as it is now, signed with the private key at ``key_path``."""
    from surrol_data.datasets.schema import utc_now_iso

    key = _load_private(key_path)
    digest = manifest_digest(root)
    return {"algorithm": "ed25519", "public_key": _public_hex(key.public_key()), "signed_at": utc_now_iso(),
            "manifest_sha256": digest, "signature": key.sign(_message(digest)).hex()}


def sign(root: str | Path, key_path: str | Path) -> dict:
    """Sign ``root`` (a sealed dataset) with the private key at ``key_path``: the signature entry is written into
    its sidecar (atomically, holding the dataset's lock); returns it."""
    from surrol_data.datasets.info import read_sidecar
    from surrol_data.datasets.lock import DatasetLock
    from surrol_data.datasets.schema import SIDECAR_PATH
    from surrol_data.datasets.writer import _write_json_atomic

    root = Path(root)
    if not read_sidecar(root).get("seals"):
        raise DatasetError(f"{root} has no seals to sign (recorded before seals existed): `surrol-data filter "
                           f"{root} --where 'seed >= 0' --out NEW` makes a sealed copy; sign that")
    with DatasetLock(root):
        entry = signature_entry(root, key_path)
        side = read_sidecar(root)
        side[SIGNATURE] = entry
        _write_json_atomic(root / SIDECAR_PATH, side)
    return entry


def verify(root: str | Path, trusted) -> list[str]:
    """Why ``root``'s signature does not hold for the ``trusted`` public key (:func:`load_public`); [] when it does."""
    from cryptography.exceptions import InvalidSignature

    from surrol_data.datasets.info import read_sidecar

    side = read_sidecar(root)
    entry = side.get(SIGNATURE)
    if not isinstance(entry, dict) or "signature" not in entry:
        return ["it is not signed (no signature in meta/surrol_data.json): its provenance cannot be traced to the "
                "trusted key"]
    want = _public_hex(trusted)
    if entry.get("public_key") != want:
        return [f"it is signed by key {str(entry.get('public_key'))[:16]}…, not by the trusted key {want[:16]}…"]
    if not side.get("seals"):
        return ["its seals were dropped (the sidecar no longer says its episodes are sealed)"]
    digest = manifest_digest(root)
    try:
        trusted.verify(bytes.fromhex(entry["signature"]), _message(digest))
    except (InvalidSignature, ValueError):
        said = ("its seals are not the ones signed: an episode's provenance or video was changed and re-sealed, a "
                "seal dropped, or episodes added, removed or reordered since it was signed")
        if entry.get("manifest_sha256") == digest:
            said = "the signature itself is forged or damaged"
        return [said]
    return []
