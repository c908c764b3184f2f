"""Shared pytest configuration: deterministic hypothesis profiles and the hardware opt-in."""

from __future__ import annotations

import os

import pytest
from hypothesis import HealthCheck, settings

# "ci": derandomized and bounded so a CI run is reproducible and cannot hang on slow runners.
settings.register_profile(
    "ci",
    derandomize=True,
    max_examples=25,
    deadline=None,
    print_blob=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
)
settings.register_profile("dev", max_examples=60, deadline=None)
settings.register_profile("thorough", max_examples=1000, deadline=None)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "ci"))


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption(
        "--hw-bench",
        default=None,
        help="bench.toml of real hardware; tests marked 'hw' run only when it is given",
    )


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if config.getoption("--hw-bench"):
        return
    skip_hw = pytest.mark.skip(reason="real hardware: pass --hw-bench bench.toml to run")
    for item in items:
        if "hw" in item.keywords:
            item.add_marker(skip_hw)


@pytest.fixture
def shared_data():
    """The ``require_shared`` function: ``shared_data('taxim_gelsight_ball')`` or skip."""
    from tests._data import require_shared

    return require_shared
