"""The Unity package (client_sdk/csharp) installs by git URL: every asset has its .meta,
GUIDs are unique and never change once given (Tests~/meta-guids.tsv), and package.json
names its samples and the Unity modules it uses."""

from __future__ import annotations

import importlib.util
import json
import shutil
from pathlib import Path
from types import ModuleType

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "client_sdk" / "csharp"


def _load() -> ModuleType:
    spec = importlib.util.spec_from_file_location(
        "unity_meta", PACKAGE / "Tests~" / "unity_meta.py"
    )
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


meta = _load()


def test_every_asset_has_a_meta_with_a_unique_published_guid() -> None:
    assert meta.check() == []
    assets = meta.assets()
    assert "Runtime/Unity/PosecastAvatarManager.cs" in assets
    assert "package.json" in assets and "CHANGELOG.md" in assets
    assert not any(a.startswith(("Tests~", "Samples~")) for a in assets)


def test_the_manifest_holds_every_guid_and_never_loses_one() -> None:
    known = meta.read_manifest()
    assert set(meta.assets()) <= set(known)
    assert len(set(known.values())) == len(known)


@pytest.fixture
def package(tmp_path: Path) -> tuple[Path, Path]:
    root = tmp_path / "csharp"
    shutil.copytree(PACKAGE, root, ignore=shutil.ignore_patterns("Tests~", "Samples~"))
    manifest = tmp_path / "meta-guids.tsv"
    shutil.copy(meta.MANIFEST, manifest)
    return root, manifest


def test_the_check_fails_for_a_missing_meta_and_write_adds_a_stable_one(
    package: tuple[Path, Path],
) -> None:
    root, manifest = package
    (root / "Runtime" / "Unity" / "New.cs").write_text("class New {}\n")
    assert meta.check(root, manifest) == [
        "Runtime/Unity/New.cs: no .meta (run unity_meta.py --write)",
    ]
    assert meta.write(root, manifest) == ["Runtime/Unity/New.cs"]
    assert meta.check(root, manifest) == []
    guid = meta.read_guid(root / "Runtime" / "Unity" / "New.cs.meta")
    assert guid == meta.derive_guid("Runtime/Unity/New.cs")
    assert meta.read_manifest(manifest)["Runtime/Unity/New.cs"] == guid


def test_the_check_fails_for_a_changed_or_duplicated_guid(package: tuple[Path, Path]) -> None:
    root, manifest = package
    driver = root / "Runtime" / "Unity" / "PosecastAvatarDriver.cs.meta"
    published = meta.read_guid(driver)
    driver.write_text(driver.read_text().replace(published, "0" * 32))
    assert meta.check(root, manifest) == [
        f"Runtime/Unity/PosecastAvatarDriver.cs.meta: guid {'0' * 32}, "
        f"but it was published as {published}",
    ]
    other = meta.read_guid(root / "Runtime" / "Unity" / "UnityFrames.cs.meta")
    driver.write_text(driver.read_text().replace("0" * 32, other))
    problems = meta.check(root, manifest)
    clash = f"guid {other} is also Runtime/Unity/PosecastAvatarDriver.cs's"
    assert f"Runtime/Unity/UnityFrames.cs.meta: {clash}" in problems


def test_a_moved_file_keeps_no_other_files_guid_and_stale_metas_are_found(
    package: tuple[Path, Path],
) -> None:
    root, manifest = package
    (root / "Runtime" / "Unity" / "UnityFrames.cs").unlink()
    assert meta.check(root, manifest) == [
        "Runtime/Unity/UnityFrames.cs.meta: no such asset (a stale .meta)"
    ]
    folder = root / "Runtime" / "Extra"
    folder.mkdir()
    (root / "Runtime" / "Extra.meta").write_text("fileFormatVersion: 2\nguid: " + "1" * 32 + "\n")
    assert "Runtime/Extra.meta: a folder's .meta without folderAsset: yes" in meta.check(
        root, manifest
    )


def test_package_json_declares_its_unity_modules_and_samples() -> None:
    package = json.loads((PACKAGE / "package.json").read_text("utf-8"))
    assert package["name"] == "com.posecast.client"
    deps = package["dependencies"]
    for module in ("com.unity.modules.xr", "com.unity.modules.animation"):
        assert module in deps
    for sample in package["samples"]:
        assert (PACKAGE / sample["path"]).is_dir(), sample
        assert sample["path"].startswith("Samples~/")
    changelog = (PACKAGE / "CHANGELOG.md").read_text("utf-8")
    assert f"## [{package['version']}]" in changelog
