"""The FastAPI application: ``create_app(settings, enqueue)``; ``app`` for uvicorn
(``uvicorn service.api.app:app``, built on first access from the environment's settings)."""

from __future__ import annotations

import gc
import logging
import sys
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi.staticfiles import StaticFiles
from starlette.concurrency import run_in_threadpool

from service.api import events, missions, system
from service.api.admission import install_replay
from service.api.body_limit import BodyLimit
from service.api.deps import Enqueue, Services
from service.api.errors import install_handlers
from service.api.fast_read import FastMissionRead
from service.api.server_timing import ServerTiming
from service.db import Database
from service.settings import Settings, get_settings

log = logging.getLogger("ltlnav.api")

OPEN_API_WARNING = (
    "no API keys configured (LTLNAV_API_KEYS): the API is open, anyone who can reach it "
    "can submit and read missions"
)


def default_enqueue(settings: Settings) -> Enqueue:
    """Enqueue through Celery (``service.jobs.tasks.enqueue_mission``), imported on first use."""

    def enqueue(mission_id: str) -> None:
        from service.jobs.tasks import enqueue_mission

        enqueue_mission(mission_id, settings)

    return enqueue


def _import_worker_code() -> None:
    try:
        import service.jobs.tasks  # noqa: F401
    except Exception as error:
        log.warning("cannot load the worker code to enqueue missions: %s", error)


async def warm_up_enqueue() -> None:
    """Import the Celery task module (Celery, kombu's transports: about a second) at start-up
    rather than in the first submission."""
    await run_in_threadpool(_import_worker_code)


GIL_SWITCH_SECONDS = 0.001
"""How long a thread may hold the interpreter lock while others wait (Python's default: 5 ms):
a read waits for it at each of its hops between the event loop and the thread pool while a
submission is validated."""


def prepare_interpreter_for_requests() -> None:
    """Move what start-up built (modules, the app, the routes) out of the garbage collector's
    reach (a full collection over them stalled every request for tens of milliseconds), and
    hand the interpreter lock on sooner."""
    gc.collect()
    gc.freeze()
    sys.setswitchinterval(GIL_SWITCH_SECONDS)


def create_app(settings: Settings | None = None, enqueue: Enqueue | None = None) -> FastAPI:
    """The API on ``settings`` (default: the environment's), sending new missions to
    ``enqueue`` (default: Celery)."""
    settings = settings or get_settings()
    services = Services(
        settings=settings,
        database=Database(settings.database_url),
        enqueue=enqueue or default_enqueue(settings),
    )
    celery_enqueue = enqueue is None

    @asynccontextmanager
    async def lifespan(_app: FastAPI) -> AsyncIterator[None]:
        if not settings.api_keys:
            log.warning(OPEN_API_WARNING)
        if celery_enqueue:
            await warm_up_enqueue()
        services.health.start()
        prepare_interpreter_for_requests()
        try:
            yield
        finally:
            await run_in_threadpool(services.health.stop)
            services.database.dispose()

    app = FastAPI(
        title="ltlnav",
        version="0.1.0",
        description="Plan LTL robot missions and train their control policies.",
        lifespan=lifespan,
    )
    app.state.services = services
    app.add_middleware(FastMissionRead)
    app.add_middleware(BodyLimit, max_body_bytes=settings.max_body_bytes)
    app.add_middleware(ServerTiming)
    install_handlers(app)
    install_replay(app)
    app.include_router(missions.router)
    app.include_router(events.router)
    app.include_router(system.router)
    if system.STATIC_DIR.is_dir():
        app.mount("/static", StaticFiles(directory=system.STATIC_DIR), name="static")
    return app


_default_app: FastAPI | None = None


def __getattr__(name: str) -> FastAPI:
    # ``app`` is built on first access so that importing this module has no side effects.
    global _default_app
    if name != "app":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    if _default_app is None:
        _default_app = create_app()
    return _default_app
