"""The Unity package's .meta files: write the missing ones, or check them all.

Unity imports an asset only with a ``.meta`` beside it, and a package added by git URL
is read-only, so every file and folder of client_sdk/csharp ships its ``.meta``
(Unity skips names that start with ``.`` or end with ``~``, such as ``Tests~`` and
``Samples~``, and everything inside them). A GUID is how scenes and prefabs refer to
an asset (a MonoBehaviour's script above all), so it must never change once
published: a new asset's GUID is derived from its path (md5 of
``com.posecast.client:<path>``, so two checkouts write the same one), and
``Tests~/meta-guids.tsv`` records every GUID ever given, path to GUID, which the
check holds every ``.meta`` to, even after a file moves or its derivation would
differ.

    python client_sdk/csharp/Tests~/unity_meta.py           # check (exit 1 on a problem)
    python client_sdk/csharp/Tests~/unity_meta.py --write   # add the missing .meta files
"""

from __future__ import annotations

import hashlib
import re
import sys
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent
MANIFEST = PACKAGE / "Tests~" / "meta-guids.tsv"
PACKAGE_NAME = "com.posecast.client"

_GUID = re.compile(r"^guid: ([0-9a-f]{32})$", re.MULTILINE)

_TAIL = "  userData: \n  assetBundleName: \n  assetBundleVariant: \n"

# The importer Unity writes for each kind of asset (what it would write itself on import).
_IMPORTERS = {
    ".cs": (
        "MonoImporter:\n  externalObjects: {}\n  serializedVersion: 2\n  defaultReferences: []\n"
        "  executionOrder: 0\n  icon: {instanceID: 0}\n" + _TAIL
    ),
    ".asmdef": "AssemblyDefinitionImporter:\n  externalObjects: {}\n" + _TAIL,
    ".json": "TextScriptImporter:\n  externalObjects: {}\n" + _TAIL,
    ".md": "TextScriptImporter:\n  externalObjects: {}\n" + _TAIL,
}
_DEFAULT = "DefaultImporter:\n  externalObjects: {}\n" + _TAIL


def ignored(name: str) -> bool:
    """Names Unity's asset database skips (and everything below them)."""
    return (
        name.startswith(".") or name.endswith("~") or name.endswith(".tmp") or name.lower() == "cvs"
    )


def assets(root: Path = PACKAGE) -> list[str]:
    """Every file and folder Unity imports from the package, as paths relative to it."""
    found: list[str] = []

    def walk(folder: Path) -> None:
        for entry in sorted(folder.iterdir()):
            if ignored(entry.name) or entry.name.endswith(".meta"):
                continue
            found.append(entry.relative_to(root).as_posix())
            if entry.is_dir():
                walk(entry)

    walk(root)
    return found


def derive_guid(path: str) -> str:
    """The GUID a new asset at `path` (relative to the package) is given."""
    return hashlib.md5(f"{PACKAGE_NAME}:{path}".encode()).hexdigest()


def meta_text(path: str, guid: str, folder: bool) -> str:
    head = f"fileFormatVersion: 2\nguid: {guid}\n"
    if folder:
        return head + "folderAsset: yes\n" + _DEFAULT
    return head + _IMPORTERS.get(Path(path).suffix, _DEFAULT)


def read_manifest(path: Path = MANIFEST) -> dict[str, str]:
    out: dict[str, str] = {}
    if path.exists():
        for line in path.read_text("utf-8").splitlines():
            if line and not line.startswith("#"):
                p, g = line.split("\t")
                out[p] = g
    return out


def write_manifest(entries: dict[str, str], path: Path = MANIFEST) -> None:
    lines = ["# path\tguid: every GUID given; never edit or remove a line (unity_meta.py)"]
    lines += [f"{p}\t{g}" for p, g in sorted(entries.items())]
    path.write_text("\n".join(lines) + "\n", "utf-8")


def read_guid(meta: Path) -> str | None:
    m = _GUID.search(meta.read_text("utf-8"))
    return m.group(1) if m else None


def check(root: Path = PACKAGE, manifest: Path = MANIFEST) -> list[str]:
    """Every problem with the package's .meta files: none when it is complete."""
    problems: list[str] = []
    known = read_manifest(manifest)
    wanted = assets(root)
    seen: dict[str, str] = {}
    for path in wanted:
        meta = root / (path + ".meta")
        if not meta.exists():
            problems.append(f"{path}: no .meta (run unity_meta.py --write)")
            continue
        guid = read_guid(meta)
        if guid is None:
            problems.append(f"{path}.meta: no 32-hex-digit guid")
            continue
        if guid in seen:
            problems.append(f"{path}.meta: guid {guid} is also {seen[guid]}'s")
        seen[guid] = path
        if (root / path).is_dir() and "folderAsset: yes" not in meta.read_text("utf-8"):
            problems.append(f"{path}.meta: a folder's .meta without folderAsset: yes")
        if path not in known:
            problems.append(f"{path}: not in {manifest.name} (run unity_meta.py --write)")
        elif known[path] != guid:
            problems.append(f"{path}.meta: guid {guid}, but it was published as {known[path]}")
    reused = {g: p for p, g in known.items()}
    for guid, path in seen.items():
        if reused.get(guid, path) != path:
            problems.append(f"{path}.meta: guid {guid} was {reused[guid]}'s")
    on_disk = set(wanted)
    for meta in sorted(root.rglob("*.meta")):
        rel = meta.relative_to(root).as_posix()[: -len(".meta")]
        if any(ignored(part) for part in Path(rel).parts):
            continue
        if rel not in on_disk:
            problems.append(f"{rel}.meta: no such asset (a stale .meta)")
    return problems


def write(root: Path = PACKAGE, manifest: Path = MANIFEST) -> list[str]:
    """Add the missing .meta files (the manifest's GUID, else a derived one); their paths."""
    known = read_manifest(manifest)
    added: list[str] = []
    for path in assets(root):
        meta = root / (path + ".meta")
        if not meta.exists():
            given = known.get(path) or derive_guid(path)
            meta.write_text(meta_text(path, given, (root / path).is_dir()), "utf-8")
            added.append(path)
        guid = read_guid(meta)
        if guid is not None and path not in known:
            known[path] = guid
    write_manifest(known, manifest)
    return added


def main(argv: list[str]) -> int:
    if "--write" in argv:
        for path in write():
            print(f"wrote {path}.meta")
    problems = check()
    for p in problems:
        print(f"error [META] {p}", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
