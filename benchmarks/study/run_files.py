"""The study's per-run result files: RUNS/<case>/<method>/b<B>-s<S>.json.gz (RUNS is
OUT/runs; the key is study_plan.Run.key).

Each holds study_run's JSON result with run_study.py's "study" block, gzip-compressed with
the header's time set to 0, so the same result always gives the same bytes (`gunzip -k`
or `zcat` gives the JSON). Plain .json files, how runs were stored before, are read as
well; where a run has both, the .json.gz is the one read.
"""
from __future__ import annotations

import gzip
import json
import zlib
from pathlib import Path

SUFFIX = ".json.gz"
PLAIN = ".json"  # the earlier format, read only


def path_of(runs_dir: Path, key: str) -> Path:
    """Where the run `key` is written."""
    return runs_dir / (key + SUFFIX)


def plain_path_of(runs_dir: Path, key: str) -> Path:
    return runs_dir / (key + PLAIN)


def existing(runs_dir: Path, key: str) -> Path | None:
    """The file that holds the run `key` (the .json.gz, else a plain .json), or None."""
    for f in (path_of(runs_dir, key), plain_path_of(runs_dir, key)):
        if f.is_file():
            return f
    return None


def _stem(f: Path) -> Path | None:
    for suffix in (SUFFIX, PLAIN):
        if f.name.endswith(suffix):
            return f.with_name(f.name[:-len(suffix)])
    return None


def files(folder: Path, recursive: bool = True) -> list[Path]:
    """The run files in `folder` (and below it when recursive), one per run, in the order of
    their keys (which is the order of the plain files' paths before)."""
    found: dict[Path, Path] = {}
    for f in (folder.rglob("*.json*") if recursive else folder.glob("*.json*")):
        stem = _stem(f)
        if stem is None or not f.is_file():
            continue
        if stem not in found or f.name.endswith(SUFFIX):
            found[stem] = f
    return [found[s] for s in sorted(found)]


def read(f: Path) -> dict:
    """A run file's JSON; OSError or ValueError (json.JSONDecodeError included) when it
    cannot be read, e.g. a truncated or corrupt file."""
    data = f.read_bytes()
    if f.name.endswith(".gz"):
        try:
            data = gzip.decompress(data)
        except (EOFError, zlib.error) as e:
            raise ValueError(f"{f}: {e}") from e
    return json.loads(data)


def compressed(text: str) -> bytes:
    """The bytes of a .json.gz holding `text`: the same text gives the same bytes."""
    return gzip.compress(text.encode(), compresslevel=9, mtime=0)


def write(runs_dir: Path, key: str, result: dict) -> Path:
    """Write the run `key` as .json.gz and remove a plain .json of it left by an earlier
    checkout, so that each run has one file."""
    f = path_of(runs_dir, key)
    f.parent.mkdir(parents=True, exist_ok=True)
    tmp = f.with_name(f.name + ".tmp")
    tmp.write_bytes(compressed(json.dumps(result, indent=1) + "\n"))
    tmp.replace(f)
    plain_path_of(runs_dir, key).unlink(missing_ok=True)
    return f
