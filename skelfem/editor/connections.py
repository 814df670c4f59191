"""The editor's HTTP connections: a header timeout, a connection limit idle sockets cannot hold, one-line logs.

uvicorn (0.17) has no header timeout, and its ``limit_concurrency`` counts
open connections: 64 sockets that sent half a request line made it answer
503 to everyone, for ever. Here a connection must send a request's headers
within ``header_timeout`` seconds (from when it opens, or from the end of its
previous response) or it is closed; beyond ``max_connections`` open
connections the oldest idle one (no request in flight) is closed to make
room, so idle sockets cannot lock the page out. A malformed request is
answered 400 with one warning line, not a traceback.
"""
from __future__ import annotations

import logging
import time

LOGGERS = ("uvicorn", "uvicorn.error", "uvicorn.protocols")


class OneLine(logging.Filter):
    """Drop a record's traceback (uvicorn logs one for every malformed request); keep its line."""

    def filter(self, record):
        if record.exc_info:
            exc = record.exc_info[1]
            if exc is not None:
                record.msg = f"{record.getMessage()} ({type(exc).__name__}: {str(exc)[:200]})"
                record.args = ()
            record.exc_info, record.exc_text = None, None
        record.stack_info = None
        return True


_FILTER = OneLine()


def one_line_logs() -> None:
    """uvicorn's loggers print one line per problem (installed when an editor serves)."""
    for name in LOGGERS:
        logger = logging.getLogger(name)
        if _FILTER not in logger.filters:
            logger.addFilter(_FILTER)


def protocol_class(header_timeout: float, max_connections: int):
    """uvicorn's h11 protocol with a header timeout and a connection limit that evicts idle connections."""
    import h11
    from uvicorn.protocols.http.h11_impl import H11Protocol

    class Protocol(H11Protocol):
        def connection_made(self, transport):
            super().connection_made(transport)
            self.opened = time.monotonic()
            self.header_timer = None
            self.arm()
            mine = [c for c in self.connections if isinstance(c, Protocol)]
            if len(mine) > max_connections:
                idle = sorted((c for c in mine if c is not self and c.idle()), key=lambda c: c.opened)
                for c in idle[:len(mine) - max_connections]:
                    c.drop()
                if len(mine) - len(idle) > max_connections:   # every other one has a request in flight
                    self.drop()

        def idle(self) -> bool:
            return (self.cycle is None or self.cycle.response_complete) and self.conn.their_state is h11.IDLE

        def drop(self) -> None:
            self.disarm()
            if self.transport is not None and not self.transport.is_closing():
                self.transport.close()

        def arm(self) -> None:
            """Start the header clock while the client has not finished a request's headers."""
            waiting = self.conn.their_state is h11.IDLE and self.idle()
            if waiting and self.header_timer is None and self.transport is not None:
                self.header_timer = self.loop.call_later(header_timeout, self.drop)
            elif not waiting:
                self.disarm()

        def disarm(self) -> None:
            if self.header_timer is not None:
                self.header_timer.cancel()
                self.header_timer = None

        def data_received(self, data):
            super().data_received(data)
            self.arm()

        def on_response_complete(self):
            super().on_response_complete()
            self.disarm()
            self.arm()

        def connection_lost(self, exc):
            self.disarm()
            super().connection_lost(exc)

    return Protocol
