"""A deadline for the whole of one HTTP request (connect, TLS, sending, every read), not only for each read.

httpx's timeouts bound each network operation: a read that waits ``read`` seconds for a byte fails, but a
server that sends one byte a second never lets a read wait that long and holds a request for ever (seen:
``captions.timeout_s = 3`` and a dripping server held ``catalog caption`` with no end and no output).

:func:`deadline_client` makes an ``httpx.Client`` whose connections go through :class:`DeadlineBackend`:
every connect, read and write of a request is given at most the time left until the request's deadline
(and at most its own httpx timeout), so a request ends no later than its deadline whatever the server
does, with httpx's own ``TimeoutException``. The deadline is set per request and per thread with
:func:`request_deadline` (the captioner's requests run in several threads at once). Kept connections
serve later requests under those requests' deadlines.

httpx has no setting for this: the backend is given to each connection pool the client made (its own and
those of proxies from the environment) through httpcore's ``_network_backend``; :func:`arm` checks that
each pool has it, so an httpx or httpcore that changes this stops at once instead of running unbounded.
"""

from __future__ import annotations

import contextlib
import threading
import time
from typing import Any, Iterator, Optional

import httpcore
import httpx

_local = threading.local()


@contextlib.contextmanager
def request_deadline(seconds: float) -> Iterator[float]:
    """Within the block, this thread's requests on a :func:`deadline_client` end within ``seconds`` of
    now (a timeout past it). Yields the deadline (``time.monotonic()`` clock)."""
    previous = getattr(_local, "deadline", None)
    _local.deadline = time.monotonic() + float(seconds)
    try:
        yield _local.deadline
    finally:
        _local.deadline = previous


def _bounded(timeout: Optional[float], error: type[Exception]) -> Optional[float]:
    """``timeout`` cut to the time left until this thread's deadline; ``error`` when none is left."""
    deadline: Optional[float] = getattr(_local, "deadline", None)
    if deadline is None:
        return timeout
    left = float(deadline) - time.monotonic()
    if left <= 0:
        raise error("the request's deadline passed")
    return left if timeout is None else min(timeout, left)


class DeadlineStream(httpcore.NetworkStream):
    """A network stream whose every operation waits at most until the request's deadline."""

    def __init__(self, stream: httpcore.NetworkStream) -> None:
        self._stream = stream

    def read(self, max_bytes: int, timeout: Optional[float] = None) -> bytes:
        return self._stream.read(max_bytes, _bounded(timeout, httpcore.ReadTimeout))

    def write(self, buffer: bytes, timeout: Optional[float] = None) -> None:
        self._stream.write(buffer, _bounded(timeout, httpcore.WriteTimeout))

    def close(self) -> None:
        self._stream.close()

    def start_tls(self, ssl_context: Any, server_hostname: Optional[str] = None,
                  timeout: Optional[float] = None) -> httpcore.NetworkStream:
        return DeadlineStream(self._stream.start_tls(ssl_context, server_hostname,
                                                     _bounded(timeout, httpcore.ConnectTimeout)))

    def get_extra_info(self, info: str) -> Any:
        return self._stream.get_extra_info(info)


class DeadlineBackend(httpcore.NetworkBackend):
    """httpcore's network backend with :class:`DeadlineStream` streams (connects bounded the same way)."""

    def __init__(self, inner: Optional[httpcore.NetworkBackend] = None) -> None:
        self._inner = inner or httpcore.SyncBackend()

    def connect_tcp(self, host: str, port: int, timeout: Optional[float] = None, local_address: Optional[str] = None,
                    socket_options: Any = None) -> httpcore.NetworkStream:
        return DeadlineStream(self._inner.connect_tcp(host, port, _bounded(timeout, httpcore.ConnectTimeout),
                                                      local_address, socket_options))

    def connect_unix_socket(self, path: str, timeout: Optional[float] = None,
                            socket_options: Any = None) -> httpcore.NetworkStream:
        return DeadlineStream(self._inner.connect_unix_socket(path, _bounded(timeout, httpcore.ConnectTimeout),
                                                              socket_options))

    def sleep(self, seconds: float) -> None:
        self._inner.sleep(seconds)


def arm(transport: Any) -> None:
    """Give the connection pool of an ``httpx.HTTPTransport`` the :class:`DeadlineBackend`."""
    pool = getattr(transport, "_pool", None)
    if pool is None or not hasattr(pool, "_network_backend"):
        raise RuntimeError(f"cannot bound the requests of {type(transport).__name__}: this httpx / httpcore keeps "
                           "its connection pool elsewhere (mixcount.captions.deadline)")
    if not isinstance(pool._network_backend, DeadlineBackend):
        pool._network_backend = DeadlineBackend(pool._network_backend)


def deadline_client(**kwargs: Any) -> httpx.Client:
    """An ``httpx.Client`` (``kwargs`` as for it) whose requests keep :func:`request_deadline`."""
    client = httpx.Client(**kwargs)
    for transport in [client._transport, *client._mounts.values()]:
        if transport is not None:
            arm(transport)
    return client
