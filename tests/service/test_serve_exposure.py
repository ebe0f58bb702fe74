"""The open API (no keys) serves loopback addresses only: ``ltlnav serve --host 0.0.0.0``
without ``LTLNAV_API_KEYS`` exits 2 before it migrates or starts anything."""

from __future__ import annotations

from pathlib import Path

import pytest
from typer.testing import CliRunner

from service.cli import app as cli
from service.serve import OpenExposureError, is_loopback, refuse_open_exposure
from service.settings import Settings


@pytest.mark.parametrize(
    ("host", "loopback"),
    [
        ("127.0.0.1", True),
        ("127.1.2.3", True),
        ("localhost", True),
        ("::1", True),
        ("[::1]", True),
        ("0.0.0.0", False),
        ("::", False),
        ("", False),
        ("192.168.1.20", False),
        ("ltlnav.example.org", False),
    ],
)
def test_is_loopback(host: str, loopback: bool) -> None:
    assert is_loopback(host) is loopback


def test_keys_allow_any_host(tmp_path: Path) -> None:
    open_api = Settings(data_dir=tmp_path, api_keys=[])
    keyed = Settings(data_dir=tmp_path, api_keys=["k1"])
    refuse_open_exposure(open_api, "127.0.0.1")
    refuse_open_exposure(keyed, "0.0.0.0")
    with pytest.raises(OpenExposureError, match="LTLNAV_API_KEYS"):
        refuse_open_exposure(open_api, "0.0.0.0")


@pytest.mark.parametrize(
    ("args", "env"),
    [
        (["--host", "0.0.0.0"], {}),
        (["--host", "10.0.0.5", "--no-worker"], {}),
        ([], {"LTLNAV_HOST": "0.0.0.0"}),
    ],
)
def test_serve_refuses_the_open_api_on_a_network(
    tmp_path: Path, args: list[str], env: dict[str, str]
) -> None:
    data = tmp_path / "data"
    environment = {"LTLNAV_API_KEYS": "", "LTLNAV_DATA_DIR": str(data), **env}
    result = CliRunner().invoke(cli, ["serve", *args], env=environment)
    assert result.exit_code == 2, result.output
    assert "LTLNAV_API_KEYS" in result.output
    assert "refusing to serve the open API" in result.output
    assert not data.exists()  # nothing migrated, nothing started
