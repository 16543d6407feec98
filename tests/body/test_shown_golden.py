"""No streamed pose changed when the shown pose's passes moved into one pipeline
(``posecast.body.pipeline.show``, issue 37): the engine's output on a seeded scenario
that runs every pass (``shown_scenario.py``) against the arrays the parent commit
``d0038e4`` streamed (``data/shown_golden.npz``, written by ``shown_scenario.main`` on
that tree; rewritten on the branch ``skate`` with ``python -m tests.body.shown_scenario
tests/body/data/shown_golden.npz``, when the planted toes, ``posecast.body.plant``, moved
the feet on purpose). Positions and rotations are held to 1e-6 (measured on the machine that
wrote the file: bit for bit), and which sample each pose shows, its blend, hold and
reach flags, exactly.

The file's last bits are this machine's: numpy's SIMD kernels and the native level
differ elsewhere, and SSI's choices follow the bits, so the test runs only where the
CPU features match the file's (``shown_scenario.machine``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.body.shown_scenario import BACKENDS, LAYOUTS, machine, run
from tests.online.engine.conftest import available_backends

GOLDEN = Path(__file__).parent / "data" / "shown_golden.npz"


@pytest.fixture(scope="module")
def golden() -> dict[str, np.ndarray]:
    with np.load(GOLDEN) as z:
        arrays = {k: z[k] for k in z.files}
    if str(arrays["machine"]) != machine():
        pytest.skip(f"golden written on {arrays['machine']}, this is {machine()}")
    return arrays


def test_the_golden_file_covers_every_backend_and_layout() -> None:
    with np.load(GOLDEN) as z:
        for backend in BACKENDS:
            for layout in LAYOUTS:
                meta = z[f"{backend}/{layout}/meta"]
                # Blends, held frames, reach-limited poses and several players each.
                assert meta[:, 4].any() and meta[:, 5].any() and meta[:, 6].any(), layout
                assert len(np.unique(meta[:, 1])) == 4, layout


@pytest.mark.parametrize("layout", LAYOUTS)
@pytest.mark.parametrize("backend", [b for b in BACKENDS if b in available_backends()])
def test_the_engine_streams_the_golden_poses(
    golden: dict[str, np.ndarray], backend: str, layout: str
) -> None:
    got = run(backend, layout)
    key = f"{backend}/{layout}"
    np.testing.assert_array_equal(got["meta"], golden[f"{key}/meta"])
    np.testing.assert_array_equal(got["scale"], golden[f"{key}/scale"])
    for field in ("positions", "rotations", "contacts"):
        np.testing.assert_allclose(got[field], golden[f"{key}/{field}"], rtol=0, atol=1e-6)
