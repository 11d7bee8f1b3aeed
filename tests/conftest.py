"""Suite-wide settings: one torch thread (2-core machines stall otherwise), Agg plots, the same
torch seed before every test, the random order's seed printed, and the `mutation` hypothesis
profile for mutation runs (`M3GD_HYPOTHESIS_PROFILE=mutation`, set by `make mutate`)."""

from __future__ import annotations

import os
import signal
from collections.abc import Iterator

import pytest
from hypothesis import Phase, settings

os.environ.setdefault("MPLBACKEND", "Agg")

import torch

torch.set_num_threads(1)

pytest_plugins = ["tests.s3_fixture"]  # s3 / s3_env: a moto S3 server on 127.0.0.1

MUTATION_EXAMPLES = 10
"""Examples per property test under the `mutation` profile (fewer if the test asks fewer)."""
MUTATION_PHASES = (Phase.explicit, Phase.generate)
"""No shrinking and no replay from the example database: a failing mutant fails on its first
counterexample, and every mutant sees the same derandomized examples."""

settings.register_profile(
    "mutation", max_examples=MUTATION_EXAMPLES, phases=MUTATION_PHASES, derandomize=True,
    database=None, deadline=None,
)
if os.environ.get("M3GD_HYPOTHESIS_PROFILE") == "mutation":
    settings.load_profile("mutation")


def _mutation_settings(own: settings) -> settings:
    """A test's own @settings capped to the mutation profile (its explicit @example kept)."""
    return settings(own, max_examples=min(own.max_examples, MUTATION_EXAMPLES),
                    phases=MUTATION_PHASES, derandomize=True, database=None, deadline=None)


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """Mutation runs only. A mutant of `packets/` (mutmut names it in `MUTANT_UNDER_TEST`) is
    judged by `tests/packets` alone: the pure math must be pinned by its own tests, and the
    select tests that also reach it ingest a bag per run. Under the `mutation` profile, the
    tests that set their own hypothesis settings are capped too (a loaded profile only changes
    the defaults, and most property tests set max_examples)."""
    if os.environ.get("MUTANT_UNDER_TEST", "").startswith("packets."):
        outside = [item for item in items if not item.nodeid.startswith("tests/packets/")]
        if outside:
            config.hook.pytest_deselected(items=outside)
            items[:] = [item for item in items if item.nodeid.startswith("tests/packets/")]
    if settings.get_current_profile_name() != "mutation":
        return
    for item in items:
        fn = getattr(item, "obj", None)
        own = getattr(fn, "_hypothesis_internal_use_settings", None)
        if isinstance(own, settings):
            fn._hypothesis_internal_use_settings = _mutation_settings(own)  # type: ignore[union-attr]


@pytest.fixture
def python_sigint() -> Iterator[None]:
    """Python's own Ctrl-C handler (KeyboardInterrupt) for the test, as in a terminal: a
    process started in the background of a shell without job control (`cmd &` in a script, some
    CI runners) inherits SIGINT ignored, and a SIGINT a test sends would never arrive."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


@pytest.fixture(autouse=True)
def _torch_seed() -> None:
    """Every test starts from the same global torch generator state, whatever ran before it
    (pytest-randomly reseeds `random` and numpy's global generator, not torch's)."""
    torch.manual_seed(0)


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter,
                            config: pytest.Config) -> None:
    """Print the random test order's seed (pytest-randomly) even under -q; a failure that
    depends on the order is repeated with `pytest --randomly-seed=N`."""
    seed = getattr(config.option, "randomly_seed", None)
    if config.pluginmanager.has_plugin("randomly") and seed is not None:
        terminalreporter.write_line(f"test order: --randomly-seed={seed}")
