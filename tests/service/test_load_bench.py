"""The load mode of the service benchmark (``bench/service_load.py``) at a small scale: real
``ltlnav serve`` and two ``ltlnav worker`` processes on the embedded backend, 5 tiny missions
(two of which cannot be planned) from 10 API keys under 5 pollers. It checks the accounting
the full run reports: every mission ended as its kind says (failed ones with a reason), no
step ran twice, no request failed, the broker table emptied and the progress events of the
ended missions pruned."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.service_load import parser, run_load

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]


def test_load_mode_accounts_for_every_mission(tmp_path: Path) -> None:
    args = parser().parse_args(
        ["--missions", "5", "--pollers", "5", "--sample", "1", "--cleanup", "2", "--limit", "90"]
    )
    result = run_load(args, "embedded", tmp_path)

    assert len(result.kinds) == 5
    assert sorted(result.kinds.values()) == ["enclosed", "gives-up", "tiny", "tiny", "tiny"]
    assert result.lost == 0
    assert result.statuses == {"done": 3, "failed": 2}
    assert result.failed_without_reason == 0
    assert result.unexpected == []
    assert result.duplicates == 0
    assert result.retried_jobs == 0 and result.jobs == 3
    assert not result.post_errors and not result.get_errors
    assert result.get_times, "the pollers read nothing"
    broker = [sample.broker for sample in result.samples if sample.broker is not None]
    assert max(broker) > 0 and broker[-1] == 0, broker
    assert result.progress_events_left == 0
    assert len(result.get_server_times) == len(result.get_times)
    assert all(
        0 < server <= client
        for server, client in zip(result.get_server_times, result.get_times, strict=True)
    ), "every read carries the API's own time, within the client's"
