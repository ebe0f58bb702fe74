"""What the routes share: settings, the database and the enqueue function of one app."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Annotated

from fastapi import Depends, Request

from service.api.examples import ExampleCatalogue
from service.db import Database
from service.settings import Settings

Enqueue = Callable[[str], None]
"""Sends a committed mission to the workers (``service.jobs.tasks.enqueue_mission``)."""


@dataclass
class Services:
    """One app's collaborators (``app.state.services``)."""

    settings: Settings
    database: Database
    enqueue: Enqueue
    examples: ExampleCatalogue = field(init=False)

    def __post_init__(self) -> None:
        self.examples = ExampleCatalogue(self.settings.examples_dir)


def services(request: Request) -> Services:
    """The ``Services`` of the app serving ``request``."""
    found: Services = request.app.state.services
    return found


Deps = Annotated[Services, Depends(services)]
"""Route parameter giving the app's ``Services``."""
