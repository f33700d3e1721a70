"""A bounded, closable hand-off from Zenoh's callback threads to consumers that block, poll or
``await``. Zenoh-python has no asyncio API: an awaiting consumer is woken with
``loop.call_soon_threadsafe`` and then takes the item itself, so one buffer serves every style.

Closing wakes every consumer at once: nobody is left blocked when the process exits.
"""

from __future__ import annotations

import asyncio
import threading
import time
from collections import deque
from collections.abc import AsyncIterator, Iterator
from typing import Generic, TypeVar

T = TypeVar("T")


class Mailbox(Generic[T]):
    """Keeps the newest ``capacity`` items; older ones are dropped (and counted) when full."""

    def __init__(self, capacity: int) -> None:
        if capacity < 1:
            raise ValueError(f"capacity must be >= 1, got {capacity}")
        self._items: deque[T] = deque(maxlen=capacity)
        self._cond = threading.Condition()
        self._waiters: dict[asyncio.Event, asyncio.AbstractEventLoop] = {}
        self._closed = False
        self.put_count = 0
        self.dropped = 0

    @property
    def closed(self) -> bool:
        return self._closed

    def __len__(self) -> int:
        return len(self._items)

    def put(self, item: T) -> None:
        """From any thread; never blocks."""
        with self._cond:
            if self._closed:
                return
            if len(self._items) == self._items.maxlen:
                self.dropped += 1
            self._items.append(item)
            self.put_count += 1
            self._cond.notify()
            waiters = list(self._waiters.items())
        self._wake(waiters)

    def close(self) -> None:
        """Wake every consumer; items already buffered can still be taken."""
        with self._cond:
            self._closed = True
            self._cond.notify_all()
            waiters = list(self._waiters.items())
        self._wake(waiters)

    def _wake(self, waiters: list[tuple[asyncio.Event, asyncio.AbstractEventLoop]]) -> None:
        for event, loop in waiters:
            try:
                loop.call_soon_threadsafe(event.set)
            except RuntimeError:  # that loop is closed: its consumer is gone
                with self._cond:
                    self._waiters.pop(event, None)

    def get(self, timeout: float | None = None) -> T | None:
        """The oldest item; waits up to ``timeout`` seconds (forever if None). None when the
        time is up, or when the mailbox is closed and empty."""
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            while not self._items:
                if self._closed:
                    return None
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    return None
                # Bounded waits keep Ctrl-C responsive in the consumer's thread.
                self._cond.wait(0.5 if remaining is None else min(remaining, 0.5))
            return self._items.popleft()

    def get_nowait(self) -> T | None:
        with self._cond:
            return self._items.popleft() if self._items else None

    def __iter__(self) -> Iterator[T]:
        """Blocking iteration; ends when the mailbox is closed and drained."""
        while True:
            item = self.get()
            if item is None:
                return
            yield item

    async def get_async(self) -> T | None:
        """The oldest item, awaiting one; None once closed and drained."""
        loop = asyncio.get_running_loop()
        event = asyncio.Event()
        with self._cond:
            self._waiters[event] = loop
        try:
            while True:
                with self._cond:
                    if self._items:
                        return self._items.popleft()
                    if self._closed:
                        return None
                    event.clear()
                await event.wait()
        finally:
            with self._cond:
                self._waiters.pop(event, None)

    async def __aiter__(self) -> AsyncIterator[T]:
        while True:
            item = await self.get_async()
            if item is None:
                return
            yield item
