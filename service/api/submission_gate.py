"""At most ``LTLNAV_SUBMISSION_CONCURRENCY`` submissions are validated and stored at once.

Validating a mission is CPU work in the API's one Python process: ten at once finish no sooner
than one after the other, but every read served meanwhile waits for the interpreter lock at
each of its hops between the event loop and the thread pool. The waiting submissions hold no
thread: they wait on the event loop."""

from __future__ import annotations

import asyncio
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from weakref import WeakKeyDictionary


class SubmissionGate:
    """A semaphore of ``slots`` per event loop (a test client runs each app on its own)."""

    def __init__(self, slots: int) -> None:
        self.slots = slots
        self._semaphores: WeakKeyDictionary[asyncio.AbstractEventLoop, asyncio.Semaphore] = (
            WeakKeyDictionary()
        )

    def _semaphore(self) -> asyncio.Semaphore:
        loop = asyncio.get_running_loop()
        semaphore = self._semaphores.get(loop)
        if semaphore is None:
            semaphore = self._semaphores[loop] = asyncio.Semaphore(self.slots)
        return semaphore

    @asynccontextmanager
    async def slot(self) -> AsyncIterator[None]:
        """One slot, waited for on the event loop."""
        async with self._semaphore():
            yield
