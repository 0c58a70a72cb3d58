"""The one interface every transport implements (python-can's BusABC pattern).

The public :meth:`Transport.transfer` is a template: it counts, times and
classifies failures; a backend implements only :meth:`Transport._transfer`.
A transfer is one combined transaction: write ``request`` (may be empty), then
read ``read_len`` bytes.  Failures raise :class:`dyno.errors.TransportError`
with ``cause`` in {"nack", "timeout", "io"}.
"""

from __future__ import annotations

import ctypes
import errno
import threading
from abc import ABC, abstractmethod
from collections import Counter

from dyno.errors import TransportError

# Linux i2c-dev reports a missing ACK as EREMOTEIO/ENXIO (i2c-algo-bit, under i2c-gpio: EIO for a data byte's),
# a hung bus as ETIMEDOUT.  The Pi's Broadcom controller (i2c-bcm2835) gives EIO for its clock-stretch timeout
# (CLKT): the transport of a bus on that controller names it so (RecoveringI2CTransport, hardware_controller).
ERRNO_CAUSE = {errno.EREMOTEIO: "nack", errno.ENXIO: "nack", errno.EIO: "nack",
                errno.ETIMEDOUT: "timeout", errno.EAGAIN: "timeout"}
STRETCH_CAUSES = {**ERRNO_CAUSE, errno.EIO: "stretch_timeout"}


class TransportFault(TransportError):
    def __init__(self, cause: str, detail: str = ""):
        self.cause = cause
        super().__init__(f"{cause}: {detail}" if detail else cause)


class Transport(ABC):
    """A link to one device: ``transfer(request, read_len) -> bytes``."""

    name = "transport"

    errno_cause = ERRNO_CAUSE  # OSError errno -> failure cause
    meter = None  # a dyno.transports.budget.LinkMeter charged each attempt's own time on the wire (None: not metered)

    def __init__(self) -> None:
        self.transfers = 0
        self.failures: Counter = Counter()

    def meter_with(self, meter, now) -> None:
        """Charge ``meter`` each attempt's own duration on ``now`` (seconds): timed around the bus transaction
        (I²C) or from the request's write to its frame (serial), so a retry's back-off is not link time."""
        self.meter, self._meter_now = meter, now

    def transfer(self, request: bytes, read_len: int) -> bytes:
        self.transfers += 1
        try:
            data = self._transfer(bytes(request), read_len)
        except TransportFault as exc:
            self.failures[exc.cause] += 1
            raise
        except OSError as exc:
            cause = self.errno_cause.get(exc.errno, "io")
            self.failures[cause] += 1
            raise TransportFault(cause, str(exc)) from exc
        return bytes(data)

    def write(self, request: bytes) -> None:
        """A write with no read (commands that get no answer)."""
        self.transfer(request, 0)

    @abstractmethod
    def _transfer(self, request: bytes, read_len: int) -> bytes:
        """Backend hook: one write-then-read transaction."""

    def close(self) -> None:  # pragma: no cover - trivial
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class I2CTransport(Transport):
    """A device on an SMBus-like object via ``i2c_rdwr`` (smbus2, or the simulated bus).

    The simulated bus implements the same ``i2c_rdwr`` call the kernel gets, so
    the host decodes identical bytes through an identical path.
    """

    name = "i2c"

    def __init__(self, bus, address: int) -> None:
        super().__init__()
        from smbus2 import i2c_msg  # thin adapter: the only place smbus2 types appear

        self._msg = i2c_msg
        self._local = threading.local()
        self.bus = bus
        self.address = address

    def _transfer(self, request: bytes, read_len: int) -> bytes:
        # The i2c_msg structures are built once per thread and length and refilled: building them
        # (two ctypes buffers a transfer) costs much of the idle poll loop's CPU.  Per thread, because
        # the kernel lets two threads transfer at once but a shared buffer would mix their bytes.
        cache = getattr(self._local, "msgs", None)
        if cache is None:
            cache = self._local.msgs = {}
        msgs = []
        if request:
            wr = cache.get(-len(request))
            if wr is None:
                wr = cache[-len(request)] = self._msg.write(self.address, request)
            else:
                ctypes.memmove(wr.buf, request, len(request))
            msgs.append(wr)
        rd = None
        if read_len:
            rd = cache.get(read_len)
            if rd is None:
                rd = cache[read_len] = self._msg.read(self.address, read_len)
            else:
                ctypes.memset(rd.buf, 0, read_len)  # as a fresh buffer: a short read leaves zeros, not old bytes
            msgs.append(rd)
        meter = self.meter
        if meter is None:
            self.bus.i2c_rdwr(*msgs)
        else:
            t0 = self._meter_now()
            try:
                self.bus.i2c_rdwr(*msgs)
            finally:
                meter.add(self._meter_now() - t0)
        return ctypes.string_at(rd.buf, read_len) if rd is not None else b""

    def close(self) -> None:
        close = getattr(self.bus, "close", None)
        if close:
            close()
