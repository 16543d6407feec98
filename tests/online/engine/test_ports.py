"""The engine's ports (online.engine.ports): every backend this install runs supplies
each member of :class:`StepDecoder` and :class:`Pool` (a Pool is a Passes too), with
the parameters the engine calls them by; and the loaders' settings default to the
contact IK's own."""

from __future__ import annotations

import inspect
import re
from pathlib import Path

import pytest

from posecast.body.ik import MAX_DRIFT_M, RELEASE_FRAMES
from posecast.body.passes import NumpyPasses, Passes
from posecast.online.engine.ports import BACKENDS, MAX_THREADS, Models, Pool, StepDecoder
from posecast.online.inference.auto import load_backend
from tests.online.engine.conftest import available_backends

ROOT = Path(__file__).resolve().parents[3]
_PROTOCOL_ONLY = {"__init__", "__subclasshook__", "__init_subclass__", "__class_getitem__"}


def _members(protocol: type) -> dict[str, object]:
    """A protocol's declared methods and attributes (its own and its bases')."""
    out: dict[str, object] = {}
    for base in reversed(protocol.__mro__):
        if base is object or base.__name__ in ("Protocol", "Generic"):
            continue
        out.update({n: None for n in getattr(base, "__annotations__", {})})
        out.update(
            {n: v for n, v in vars(base).items() if callable(v) and n not in _PROTOCOL_ONLY
             and not n.startswith("_abc")}
        )  # fmt: skip
    return out


def _conforms(obj: object, protocol: type) -> list[str]:
    """What ``obj`` lacks of ``protocol``: missing members, and methods whose parameter
    names differ from the protocol's."""
    bad = []
    for name, declared in _members(protocol).items():
        if not hasattr(obj, name):
            bad.append(f"missing {name}")
            continue
        if declared is None:
            continue
        want = list(inspect.signature(declared).parameters)[1:]  # without self
        got = list(inspect.signature(getattr(obj, name)).parameters)
        if got != want:
            bad.append(f"{name}{tuple(got)} != {tuple(want)}")
    return bad


def test_the_protocols_declare_what_the_engine_calls() -> None:
    assert {"name", "meta", "cache_width", "cache_latents", "step"} <= set(_members(StepDecoder))
    pool = set(_members(Pool))
    assert {"threshold_m", "step", "emit", "upper_body", "hinge"} <= pool
    assert set(_members(Passes)) <= pool  # a pool is a Passes


@pytest.mark.parametrize("name", available_backends())
def test_every_backend_supplies_both_ports(name: str) -> None:
    backend = load_backend(name, "hmd3+waist", threads=1)
    assert backend.name == name
    assert _conforms(backend.decoder, StepDecoder) == []
    assert _conforms(backend.pool, Pool) == []
    assert isinstance(backend.pool.threshold_m, float) and backend.pool.threshold_m > 0


def test_the_numpy_reference_is_a_passes() -> None:
    assert _conforms(NumpyPasses(), Passes) == []

    class Half:
        def emit(self, rotations, contacts, root_mat, root_pos, ik):  # type: ignore[no-untyped-def]
            raise NotImplementedError

    assert _conforms(Half(), Passes) == ["missing upper_body", "missing hinge"]


def test_models_default_to_the_contact_iks_settings_and_backends_are_named() -> None:
    m = Models("cvae_decoder", "anomaly")
    assert (m.models_dir, m.threads) == (None, 1)
    assert (m.release_frames, m.max_drift_m) == (RELEASE_FRAMES, MAX_DRIFT_M)
    assert BACKENDS == ("native", "onnx", "torch")
    native = (ROOT / "server" / "native" / "pc_threads.c").read_text("utf-8")
    found = re.search(r"^#define MAX_THREADS (\d+)$", native, re.M)
    assert found is not None and int(found.group(1)) == MAX_THREADS  # the kernels' pool
