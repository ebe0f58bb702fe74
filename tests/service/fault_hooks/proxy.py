"""A TCP proxy on 127.0.0.1 that can be paused: a database or broker outage for the processes
that connect through it, while the real server keeps running for everyone else.

It runs an asyncio loop in a thread of the process that starts it. ``pause()`` cuts every open
connection and refuses new ones (accepted and closed at once: a client sees its server gone);
``resume()`` forwards again. ``stop()`` closes everything; the proxy is also a context manager.
"""

from __future__ import annotations

import asyncio
import contextlib
import socket
import threading
from types import TracebackType


class PauseProxy:
    """Forward ``127.0.0.1:<port>`` to ``127.0.0.1:<target_port>`` until paused."""

    def __init__(self, target_port: int, target_host: str = "127.0.0.1") -> None:
        self.target = (target_host, target_port)
        self.paused = False
        self.refused = 0
        """Connections refused while paused."""
        self._loop = asyncio.new_event_loop()
        self._writers: set[asyncio.StreamWriter] = set()
        self._server: asyncio.Server | None = None
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        sock.bind(("127.0.0.1", 0))
        self.port: int = sock.getsockname()[1]
        self._sock = sock
        self._thread = threading.Thread(target=self._run, daemon=True, name="fault-proxy")
        self._ready = threading.Event()

    def start(self) -> PauseProxy:
        """Start forwarding (in a thread); returns self."""
        self._thread.start()
        if not self._ready.wait(10):
            raise RuntimeError("the proxy did not start")
        return self

    def _run(self) -> None:
        asyncio.set_event_loop(self._loop)

        async def serve() -> None:
            self._server = await asyncio.start_server(self._handle, sock=self._sock)
            self._ready.set()

        self._loop.run_until_complete(serve())
        self._loop.run_forever()

    async def _handle(self, reader: asyncio.StreamReader, writer: asyncio.StreamWriter) -> None:
        if self.paused:
            self.refused += 1
            writer.transport.abort()
            return
        try:
            up_reader, up_writer = await asyncio.open_connection(*self.target)
        except OSError:
            writer.transport.abort()
            return
        self._writers.update((writer, up_writer))

        async def pipe(src: asyncio.StreamReader, dst: asyncio.StreamWriter) -> None:
            with contextlib.suppress(OSError, asyncio.IncompleteReadError):
                while data := await src.read(65536):
                    dst.write(data)
                    await dst.drain()
            dst.transport.abort()

        await asyncio.gather(pipe(reader, up_writer), pipe(up_reader, writer))
        self._writers.difference_update((writer, up_writer))

    def _cut(self) -> None:
        for writer in list(self._writers):
            writer.transport.abort()
        self._writers.clear()

    def pause(self) -> None:
        """Cut every connection and refuse new ones until ``resume()``."""
        self.paused = True
        done = threading.Event()

        def cut() -> None:
            self._cut()
            done.set()

        self._loop.call_soon_threadsafe(cut)
        done.wait(10)

    def resume(self) -> None:
        """Forward new connections again."""
        self.paused = False

    def stop(self) -> None:
        """Close the listener and every connection, end the thread."""
        if not self._thread.is_alive():
            self._sock.close()
            return

        async def close() -> None:
            self._cut()
            if self._server is not None:
                self._server.close()

        asyncio.run_coroutine_threadsafe(close(), self._loop).result(10)
        self._loop.call_soon_threadsafe(self._loop.stop)
        self._thread.join(10)

    def __enter__(self) -> PauseProxy:
        return self.start()

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        trace: TracebackType | None,
    ) -> None:
        self.stop()
