"""Shared helpers for the core tests (no rclpy here)."""

from pathlib import Path

import pytest

EXPERIMENTS = Path(__file__).resolve().parents[2] / 'config' / 'experiments'


@pytest.fixture
def experiments_dir() -> Path:
    return EXPERIMENTS
