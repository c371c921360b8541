"""Fixtures of the urban tests: real SUMO networks built once per session with the real tools."""

from pathlib import Path

import pytest

from models.urban.network import artificial_network


@pytest.fixture(scope="session")
def sc1_net(tmp_path_factory) -> Path:
    return artificial_network(1, tmp_path_factory.mktemp("nets") / "sc1.net.xml")
