"""What a run may replace in an output folder, and the staging folders runs leave behind.

The output folder owns only what it made. A plant folder ``OUT/<plant>`` may be replaced by a
run's folder when every entry in it is ours: the files its ``run.json`` lists (changed by hand or
not), ``run.json`` itself, and the files a parameter sweep writes (`SWEEP_FILES`, which have no
run.json). An empty folder is ours too. Anything else (a user's ``my_thesis.tex``, a folder of
their own, a ``run.json`` that is not one of ours) makes the folder the user's: it is refused with
a `ForeignFolderError` naming it and those files, and nothing of the run is published. Hidden
entries (a name starting with ".", as an editor's swap file) are not counted, as
`studies.writers.check_study_folder` does not count them.

A run stages its plant folders in ``OUT/.run-<id>.<random>.partial/`` (`new_staging`), which holds
an owner record (`STAGING_OWNER`: the run id, the PID, the host and the process's start time). A
process killed with SIGKILL cannot remove it; the next run removes every staging folder whose owner
is gone (same host, that PID not running, or running with another start time) and names in a
`StagingLeftOver` warning each one it cannot judge (another host, no readable record), which it
leaves alone.
"""

from __future__ import annotations

import json
import os
import shutil
import socket
import warnings
from collections.abc import Iterable
from pathlib import Path

from models.files import fresh_folder, write_json

#: Files ``python -m studies --sweep`` writes into a plant folder (`studies.sweep.write_sweep`), without
#: a run.json.
SWEEP_FILES = ("sweep.csv", "sweep.md", "sweep.png")
#: The owner record of a staging folder.
STAGING_OWNER = ".owner.json"
#: How many of a folder's foreign entries a message names.
NAMED = 8


class ForeignFolderError(FileExistsError):
    """Plant folders of the output folder hold entries no run of ours wrote: none is replaced.

    Attributes
    ----------
    folders : dict
        Each refused folder (a `Path`) -> the names of its entries that are not ours, sorted.
    """

    def __init__(self, folders: dict[Path, list[str]]):
        self.folders = dict(folders)
        described = "; ".join(
            f"{str(folder)!r} holds {', '.join(names[:NAMED])}{' ...' if len(names) > NAMED else ''}"
            for folder, names in self.folders.items()
        )
        super().__init__(
            f"not replacing a folder that is not ours: {described} (no run.json of a study run lists "
            f"{'them' if sum(map(len, self.folders.values())) > 1 else 'it'}); nothing of this run was published. "
            "Move those files elsewhere, or write to another output folder"
        )


class StagingLeftOver(UserWarning):
    """A staging folder of another run is in the output folder and may be a leftover; it is kept."""


# ---------------------------------------------------------------------------- what is ours
def _our_manifest(folder: Path) -> set[str] | None:
    """The names ``folder/run.json`` says its run wrote (run.json included), or None when it has none of
    ours (missing, unreadable, or without a run id and a SHA-256 manifest)."""
    try:
        info = json.loads((folder / "run.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    if not isinstance(info, dict) or not isinstance(info.get("run_id"), str):
        return None
    manifest = info.get("sha256")
    if not isinstance(manifest, dict) or not all(isinstance(name, str) for name in manifest):
        return None
    return {"run.json", *manifest}


def foreign_entries(folder: str | os.PathLike) -> list[str]:
    """The entries of the plant folder `folder` that no run of ours wrote, sorted; [] when a run may
    replace it (absent, empty, or holding only what its run.json lists and a sweep's files).

    Parameters
    ----------
    folder : ``OUT/<plant>`` (a symbolic link is followed: what it points to is judged)
    """
    folder = Path(folder)
    if not folder.is_dir():
        return []
    names = sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))
    ours = set(SWEEP_FILES) | (_our_manifest(folder) or set())
    return [name for name in names if name not in ours]


def check_output_folder(out: str | os.PathLike, names: Iterable[str]) -> None:
    """Refuse, before any work, a run whose plant folders ``out/<name>`` (for each of `names`) are not all
    ours to replace (`foreign_entries`).

    Raises
    ------
    ForeignFolderError
        Naming every refused folder and its entries that are not ours.
    """
    out = Path(out)
    refused = {out / name: found for name in names if (found := foreign_entries(out / name))}
    if refused:
        raise ForeignFolderError(refused)


# ---------------------------------------------------------------------------- staging folders
def process_start(pid: int) -> int | None:
    """The start time of process `pid` in clock ticks since boot (``/proc/<pid>/stat``, field 22), or None
    where it cannot be read (not Linux, no such process)."""
    try:
        with open(f"/proc/{int(pid)}/stat", encoding="ascii", errors="replace") as handle:
            text = handle.read()
        return int(text[text.rindex(")") + 2 :].split()[19])
    except (OSError, ValueError, IndexError):
        return None


def owner_record(run_id: str) -> dict:
    """The owner record of a staging folder made by this process for run `run_id`."""
    pid = os.getpid()
    return {"run_id": run_id, "pid": pid, "host": socket.gethostname(), "started": process_start(pid)}


def owner_gone(record) -> bool | str:
    """True when the process that wrote the owner `record` is gone, False when it may still run, or a
    sentence saying why that cannot be told (another host, a record without a PID)."""
    if not isinstance(record, dict) or not isinstance(record.get("pid"), int) or record["pid"] <= 0:
        return "its owner record names no process"
    if record.get("host") != socket.gethostname():
        return f"it belongs to a run on the host {record.get('host')!r}, not this one"
    pid = record["pid"]
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:
        pass  # a process of another user has that PID
    started = record.get("started")
    if isinstance(started, int):
        now = process_start(pid)
        return now is not None and now != started
    return False


def remove_stale_stagings(out: str | os.PathLike) -> list[Path]:
    """Remove the staging folders ``out/.run-*.partial`` whose owner is gone (`owner_gone`); warn
    (`StagingLeftOver`) naming each one whose owner cannot be told. Returns the folders removed."""
    removed = []
    for folder in sorted(Path(out).glob(".run-*.partial")):
        if folder.is_symlink() or not folder.is_dir():
            continue
        try:
            record = json.loads((folder / STAGING_OWNER).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            record = None
        gone = owner_gone(record) if record is not None else "it has no owner record"
        if gone is True:
            shutil.rmtree(folder, ignore_errors=True)
            removed.append(folder)
        elif gone is not False:
            warnings.warn(
                f"{str(folder)!r} is a staging folder of another run, perhaps killed, kept because {gone}; "
                "remove it when no run is writing into this output folder",
                StagingLeftOver,
                stacklevel=3,
            )
    return removed


def new_staging(out: str | os.PathLike, run_id: str) -> Path:
    """A fresh hidden folder ``out/.run-<run_id>.<random>.partial`` where a run writes its plant folders,
    with its owner record (`STAGING_OWNER`), after removing the staging folders of dead runs
    (`remove_stale_stagings`)."""
    if Path(out).is_dir():
        remove_stale_stagings(out)
    staging = fresh_folder(out, f".run-{run_id}.", ".partial")
    write_json(staging / STAGING_OWNER, owner_record(run_id))
    return staging
