"""A screen's output folder: its manifest, and its rows written as they come (Parquet parts), read back on ``--resume``.

Layout of ``--out DIR``:

- ``manifest.json``: what the rows are of (``format``, the case's name and
  digest, the project's version, the screen's settings, the contingencies
  screened in order and those skipped with their reasons), written once,
  atomically, before the first row;
- ``rows/part-NNNNN.parquet``: the rows of one finished task (every law and b
  of its contingencies), written atomically (a temporary file renamed), so that
  an interrupted screen leaves only whole parts; ``NNNNN`` is the index of the
  task's first contingency in the manifest's list, so a resumed screen never
  writes over a part;
- the figures and what the command writes at the end (``heatmap.png``,
  ``cct_gain.png``), remade from every part.

``--resume`` reads the manifest and refuses a folder of another case, another
version or other settings (:func:`open_store`: one line, nothing written);
the contingencies whose rows are all there are not computed again. Pure
python (pyarrow): no ROS import.
"""

from __future__ import annotations

import json
from pathlib import Path

from nni_msgs_adapter.ros.cli_support import CliError, atomic_output, write_json

#: What ``manifest.json`` says it is, so that any other folder is refused.
FORMAT = "nni-simulate --screen rows 1"
MANIFEST = "manifest.json"
ROWS = "rows"


class ScreenStore:
    """The rows of one screen: kept in memory, and in ``folder`` when there is one."""

    def __init__(self, folder: Path | None, manifest: dict):
        self.folder, self.manifest = folder, manifest
        self.rows: list[dict] = []
        if folder is not None:
            for part in sorted((folder / ROWS).glob("part-*.parquet")):
                self.rows += _read_part(part)

    def done(self) -> set:
        """Names of the contingencies whose rows are here."""
        return {row["contingency"] for row in self.rows}

    def add(self, index: int, rows: list[dict]) -> None:
        """The rows of the task whose first contingency is number ``index``, written before they count."""
        if self.folder is not None and rows:
            _write_part(self.folder / ROWS / f"part-{index:05d}.parquet", rows)
        self.rows += rows


def _write_part(path: Path, rows: list[dict]) -> None:
    import pyarrow as pa
    import pyarrow.parquet as pq

    table = pa.Table.from_pylist(rows)
    with atomic_output(path, "wb") as handle:
        pq.write_table(table, handle)


def _read_part(path: Path) -> list[dict]:
    import pyarrow.parquet as pq

    return pq.read_table(path).to_pylist()


def _differences(found: dict, wanted: dict) -> list[str]:
    return [f"{key} {found.get(key)!r} there, {wanted.get(key)!r} here" for key in sorted(set(found) | set(wanted))
            if found.get(key) != wanted.get(key)]


def open_store(folder: Path | None, manifest: dict, resume: bool) -> ScreenStore:
    """The store of a new screen in ``folder`` (created), or of the screen there to resume.

    CliError, with nothing written, for: ``--resume`` without a folder or of a
    folder that holds no screen, or of another case, version or settings; a
    folder that already holds files without ``--resume``.
    """
    if folder is None:
        if resume:
            raise CliError("--resume needs --out DIR (the folder of the screen to continue)")
        return ScreenStore(None, manifest)
    folder = Path(folder)
    path = folder / MANIFEST
    if resume:
        try:
            found = json.loads(path.read_text())
        except FileNotFoundError:
            raise CliError(f"--resume: {folder} holds no screen ({MANIFEST} missing); nothing written") from None
        except (OSError, ValueError) as error:
            raise CliError(f"--resume: {path} cannot be read ({error}); nothing written") from None
        if not isinstance(found, dict) or found.get("format") != FORMAT:
            raise CliError(f"--resume: {path} is not a screen's manifest; nothing written")
        differs = {  # what is checked, in order, and what the refusal says of the folder
            "case_digest": lambda: f"is a screen of another case ({found.get('case')}, data "
                                   f"{str(found.get('case_digest'))[:12]}; this is {manifest['case']}, data "
                                   f"{manifest['case_digest'][:12]})",
            "software_version": lambda: f"was written by version {found.get('software_version')} (this is "
                                        f"{manifest['software_version']})",
            "settings": lambda: "is a screen with other settings ("
                                + "; ".join(_differences(found.get("settings") or {}, manifest["settings"])) + ")",
            "contingencies": lambda: f"screens other contingencies ({len(found.get('contingencies') or [])} there, "
                                     f"{len(manifest['contingencies'])} here)",
        }
        for key, refusal in differs.items():
            if found.get(key) != manifest[key]:
                raise CliError(f"--resume: {folder} {refusal()}; nothing written")
        return ScreenStore(folder, found)
    if folder.exists() and (not folder.is_dir() or any(folder.iterdir())):
        raise CliError(f"--out {folder} is not an empty folder"
                       + (" (it holds a screen: --resume continues it)" if path.exists() else "")
                       + "; nothing written")
    (folder / ROWS).mkdir(parents=True, exist_ok=True)
    write_json(path, manifest)
    return ScreenStore(folder, manifest)

