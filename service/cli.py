"""The ``ltlnav`` command line: one Typer app with every command (what they print at length
lives beside it: ``service.train_progress``, ``service.progress_printer``)."""

from __future__ import annotations

import json
import os
import sys
from enum import StrEnum
from pathlib import Path
from typing import Annotated, Any

import typer

from planner.errors import LtlnavError, PlanningError
from planner.ltl.formula import parse
from planner.ltl.translate import translate

app = typer.Typer(
    name="ltlnav",
    help="Turn LTL robot missions into plans and trained, verified control policies.",
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    add_completion=False,
)

EXIT_BAD_INPUT = 2
EXIT_INFEASIBLE = 3


class AutomatonFormat(StrEnum):
    hoa = "hoa"
    dot = "dot"
    json = "json"


def _fail(error: LtlnavError) -> typer.Exit:
    typer.echo(f"error: {error}", err=True)
    code = EXIT_INFEASIBLE if isinstance(error, PlanningError) else EXIT_BAD_INPUT
    return typer.Exit(code)


@app.command("ltl2ba")
def ltl2ba(
    formula: Annotated[str, typer.Argument(help="LTL formula, spin or letter syntax.")],
    output_format: Annotated[
        AutomatonFormat, typer.Option("--format", "-f", help="Output format.")
    ] = AutomatonFormat.hoa,
) -> None:
    """Translate an LTL formula into a Büchi automaton and print it (HOA v1 by default)."""
    try:
        automaton = translate(parse(formula))
    except LtlnavError as error:
        raise _fail(error) from error
    if output_format is AutomatonFormat.hoa:
        typer.echo(automaton.to_hoa(name=formula), nl=False)
    elif output_format is AutomatonFormat.dot:
        typer.echo(automaton.to_dot(), nl=False)
    else:
        typer.echo(json.dumps(automaton.to_json(), indent=2))


@app.command("validate")
def validate(
    mission: Annotated[Path, typer.Argument(help="Mission file (YAML or JSON).")],
) -> None:
    """Check a mission file and report every problem with its field path (the service's
    admission limits included: ``LTLNAV_MAX_...`` settings)."""
    from service.settings import get_settings
    from workers.admission import load_admitted

    try:
        spec = load_admitted(mission, get_settings().admission_limits())
    except LtlnavError as error:
        raise _fail(error) from error
    typer.echo(
        f"{mission}: valid mission '{spec.name}' ({len(spec.world.bounds)}D, {spec.robot.model})"
    )


@app.command("plan")
def plan(
    mission: Annotated[Path, typer.Argument(help="Mission file (YAML or JSON).")],
    json_out: Annotated[Path | None, typer.Option("--json", help="Write the plan as JSON.")] = None,
    plot_out: Annotated[Path | None, typer.Option("--plot", help="Write a picture (PNG).")] = None,
    seed: Annotated[int | None, typer.Option(help="Override planner.seed.")] = None,
) -> None:
    """Plan a mission (within ``LTLNAV_MAX_...``): formula -> automaton -> lasso -> sub-tasks."""
    from planner.plan import verify_plan
    from service.settings import get_settings
    from workers.admission import admitted_plan, load_admitted

    try:
        limits = get_settings().admission_limits()
        spec = load_admitted(mission, limits)
        options = spec.planner_options().model_copy(update={} if seed is None else {"seed": seed})
        world, robot = spec.build_world(), spec.robot
        result = admitted_plan(spec, world, limits, options)
    except LtlnavError as error:
        raise _fail(error) from error
    problems = verify_plan(result, world, robot.radius)
    if problems:
        typer.echo(
            "error: internal check of the plan failed:\n  " + "\n  ".join(problems), err=True
        )
        raise typer.Exit(1)
    from service.plan_summary import summary_lines

    for line in summary_lines(result, robot.radius, options.margin or 0.0):
        typer.echo(line)
    if json_out is not None:
        _write_json(json_out, result.to_json(), "plan")
    if plot_out is not None:
        from planner.plot import plot_plan

        plot_out.parent.mkdir(parents=True, exist_ok=True)
        plot_plan(world, result, plot_out, title=spec.name, guides=spec.trained_guides(result))
        typer.echo(f"picture written to {plot_out}")


def _write_json(path: Path, document: dict[str, Any], what: str) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(document, indent=1))
    typer.echo(f"{what} written to {path}")


@app.command("train")
def train(
    mission: Annotated[Path, typer.Argument(help="Mission file (YAML or JSON).")],
    out: Annotated[
        Path | None, typer.Option("--out", help="Output folder (default runs/<mission name>).")
    ] = None,
    seed: Annotated[int | None, typer.Option(help="Override training.seed.")] = None,
    jobs: Annotated[
        int | None,
        typer.Option("--jobs", min=1, help="Parallel training processes (default: cores)."),
    ] = None,
    timesteps: Annotated[
        int | None, typer.Option("--timesteps", min=1, help="Override training.n_timesteps.")
    ] = None,
    episodes: Annotated[
        int | None,
        typer.Option("--episodes", min=1, help="Override training.mission_episodes."),
    ] = None,
) -> None:
    """Plan a mission, train every sub-task, evaluate the whole mission, write DIR/bundle.zip.

    Re-running on the same folder resumes from the checkpoints."""
    from service.settings import get_settings
    from service.train_progress import TrainProgress, result_lines
    from workers.admission import load_admitted, mission_problems
    from workers.mission import MissionError
    from workers.pipeline import run_pipeline

    limits = get_settings().admission_limits()
    try:
        spec = load_admitted(mission, limits)
    except LtlnavError as error:
        raise _fail(error) from error
    update: dict[str, object] = {}
    if seed is not None:
        update["seed"] = seed
    if timesteps is not None:
        update["n_timesteps"] = timesteps
    if episodes is not None:
        update["mission_episodes"] = episodes
    if update:
        training = spec.training.model_validate({**spec.training.model_dump(), **update})
        spec = spec.model_copy(update={"training": training})
        problems = mission_problems(spec, limits)
        if problems:
            raise _fail(MissionError(problems))
    folder = out if out is not None else Path("runs") / spec.name
    with TrainProgress() as bars:
        try:
            result = run_pipeline(
                spec,
                folder,
                jobs=jobs,
                on_progress=bars.show,
                limits=limits,
                on_evaluating=bars.evaluating,
            )
        except LtlnavError as error:
            raise _fail(error) from error
    for line in result_lines(result):
        typer.echo(line)


@app.command("rollout")
def rollout(
    bundle: Annotated[Path, typer.Argument(help="A bundle.zip written by ltlnav train.")],
    episodes: Annotated[int, typer.Option("--episodes", min=1, help="Rollouts.")] = 100,
    cycles: Annotated[
        int | None, typer.Option("--cycles", min=1, help="Suffix cycles (default: the bundle's).")
    ] = None,
    seed: Annotated[int, typer.Option(help="Seed of the rollouts.")] = 0,
    plot_out: Annotated[Path | None, typer.Option("--plot", help="Write a picture (PNG).")] = None,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write the results.")] = None,
) -> None:
    """Roll out a bundle's concatenated policy on its mission and print the success rate."""
    from workers.bundle import ConcatenatedPolicy, plot_rollouts

    try:
        policy = ConcatenatedPolicy.load(bundle)
    except LtlnavError as error:
        raise _fail(error) from error
    try:
        result = policy.evaluate(episodes, seed=seed, cycles=cycles)
    finally:
        policy.close()
    typer.echo(result.summary())
    for where, kinds in sorted(result.failures.items()):
        typer.echo(f"  failures at sub-task {where}: {kinds}")
    if json_out is not None:
        _write_json(json_out, result.to_json(), "results")
    if plot_out is not None:
        plot_out.parent.mkdir(parents=True, exist_ok=True)
        plot_rollouts(policy.mission.build_world(), policy.plan, result, plot_out)
        typer.echo(f"picture written to {plot_out}")


@app.command("migrate")
def migrate(
    revision: Annotated[str, typer.Option(help="Target revision.")] = "head",
) -> None:
    """Apply the database migrations to the configured database (LTLNAV_DATABASE_URL)."""
    from sqlalchemy import make_url

    from service.db import current_revision, upgrade
    from service.settings import Settings

    url = Settings().database_url
    upgrade(url, revision)
    shown = make_url(url).render_as_string(hide_password=True)
    typer.echo(f"database {shown} at revision {current_revision(url)}")


@app.command("serve")
def serve(
    host: Annotated[
        str | None, typer.Option(help="Address to bind (default LTLNAV_HOST, 127.0.0.1).")
    ] = None,
    port: Annotated[
        int | None, typer.Option(min=1, max=65535, help="Port (default LTLNAV_PORT, 8000).")
    ] = None,
    workers: Annotated[
        int | None,
        typer.Option(
            "--workers", min=1, help="Training processes of the embedded worker (default: cores)."
        ),
    ] = None,
    no_worker: Annotated[
        bool, typer.Option("--no-worker", help="Serve the API only (workers run elsewhere).")
    ] = False,
    api_processes: Annotated[
        int | None, typer.Option(min=1, help="API processes (default LTLNAV_API_PROCESSES, 1).")
    ] = None,
) -> None:
    """Migrate the database, then run the API and one embedded worker until Ctrl-C. Without
    API keys (LTLNAV_API_KEYS) only a loopback address may be bound."""
    from service.serve import OpenExposureError, refuse_open_exposure
    from service.serve import serve as run
    from service.settings import Settings

    if api_processes is not None:
        # The API's processes read their settings from the environment.
        os.environ["LTLNAV_API_PROCESSES"] = str(api_processes)
    settings = Settings()
    try:
        refuse_open_exposure(settings, host or settings.host)
    except OpenExposureError as error:
        typer.echo(f"error: {error}", err=True)
        raise typer.Exit(EXIT_BAD_INPUT) from None
    run(
        settings,
        host=host or settings.host,
        port=port or settings.port,
        worker=not no_worker,
        concurrency=workers,
        say=lambda line: typer.echo(f"ltlnav: {line}", err=True),
    )


@app.command("worker")
def worker(
    concurrency: Annotated[
        int | None,
        typer.Option("--concurrency", "-c", min=1, help="Training processes (default: cores)."),
    ] = None,
    loglevel: Annotated[str, typer.Option(help="Celery log level.")] = "INFO",
) -> None:
    """Run a Celery worker for the configured broker and database (migrate them first)."""
    from service.jobs.celery_app import run_worker
    from service.settings import Settings

    run_worker(Settings(), concurrency=concurrency, loglevel=loglevel)


@app.command("submit")
def submit(
    mission: Annotated[
        str, typer.Argument(help="Mission file (YAML or JSON), or the name of an example.")
    ],
    url: Annotated[
        str | None,
        typer.Option(envvar="LTLNAV_URL", help="The service (default http://LTLNAV_HOST:PORT)."),
    ] = None,
    api_key: Annotated[
        str | None, typer.Option("--api-key", envvar="LTLNAV_API_KEY", help="Bearer API key.")
    ] = None,
    wait: Annotated[
        bool, typer.Option("--wait", help="Follow the progress, then download the bundle.")
    ] = False,
    out: Annotated[
        Path | None,
        typer.Option("--out", help="Folder for bundle.zip (default runs/<mission name>)."),
    ] = None,
    poll: Annotated[float, typer.Option(min=0.1, help="Seconds between progress polls.")] = 1.0,
) -> None:
    """Submit a mission to the service; with --wait print its progress until it ends and
    download its bundle (exit code 1 when it fails or is cancelled)."""
    from service.client import ServiceClient, ServiceError
    from service.progress_printer import ProgressPrinter
    from service.serve import display_host
    from service.settings import Settings
    from workers.documents import read_document

    path = Path(mission)
    if path.exists() or path.suffix:
        try:
            document = read_document(path)
        except ValueError as error:
            typer.echo(f"error: {path}: {error}", err=True)
            raise typer.Exit(EXIT_BAD_INPUT) from error
    else:
        document = {"example": mission}
    if url is None:
        settings = Settings()
        url = f"http://{display_host(settings.host)}:{settings.port}"
    with ServiceClient(url, api_key) as client:
        try:
            created = client.submit(document)
        except ServiceError as error:
            typer.echo(f"error: {error}", err=True)
            bad_input = error.status is not None and 400 <= error.status < 500
            raise typer.Exit(EXIT_BAD_INPUT if bad_input else 1) from error
        mission_id = created["id"]
        typer.echo(f"mission {mission_id} {created['status']}: {url}/missions/{mission_id}")
        if not wait:
            return
        try:
            final = client.wait(mission_id, ProgressPrinter(), poll_seconds=poll)
        except ServiceError as error:
            typer.echo(f"error: {error}", err=True)
            raise typer.Exit(1) from error
        except KeyboardInterrupt:
            typer.echo(f"stopped waiting; mission {mission_id} goes on in the service", err=True)
            raise typer.Exit(130) from None
        if final["status"] != "done":
            typer.echo(f"mission {final['status']}: {final.get('reason') or 'no reason given'}")
            raise typer.Exit(1)
        target = (out or Path("runs") / final["name"]) / "bundle.zip"
        try:
            client.download_bundle(mission_id, target)
        except ServiceError as error:
            typer.echo(f"error: {error}", err=True)
            raise typer.Exit(1) from error
    evaluation = final.get("evaluation") or {}
    if "success_rate" in evaluation:
        typer.echo(
            f"mission success rate {100 * evaluation['success_rate']:.1f} % over "
            f"{evaluation.get('episodes', '?')} rollouts"
        )
    typer.echo(f"bundle written to {target}")


def main() -> None:
    """Console-script entry point."""
    try:
        app()
    except KeyboardInterrupt:
        sys.exit(130)


if __name__ == "__main__":
    main()
