"""The pressure ADC: a microcontroller that streams force-sensor samples as text lines over a serial port.

Line protocol, version 1 (docs/hardware.md has a firmware sketch):

- host to device: ``START\\n`` begins streaming, ``STOP\\n`` ends it.
- device to host, one sample per line: ``<t_us>,<counts>*<HH>\\n`` (a ``\\r`` before the ``\\n`` is allowed).
  ``t_us`` is the device clock in microseconds, unsigned 32-bit (it wraps every 2^32 us, about 71.6 min);
  ``counts`` is the signed ADC reading; ``HH`` is two hex digits, the XOR of all bytes of ``<t_us>,<counts>``.
- lines starting with ``#`` are informational and ignored.

A line that fails the checksum or parsing, is too long, claims a device time that does not increase, or claims
to have been taken after it arrived (beyond ``clock_tolerance``) is skipped and counted, with a
``HardwareWarning`` at the 1st, 10th, 100th... skip. No valid sample within the stall timeout raises
``SensorStalled``; a failing serial port raises ``DeviceDisconnected``.
"""

from __future__ import annotations

import collections
import time
import warnings
from abc import ABC, abstractmethod
from dataclasses import dataclass

import serial

from diffstir.hardware.errors import DeviceDisconnected, HardwareError, HardwareWarning, SensorStalled

WRAP = 2**32  # device clock period [us]


@dataclass(frozen=True)
class Sample:
    """One ADC reading: device clock ``t_device`` [s] (unwrapped), host monotonic clock ``t_host`` [s] when the
    line arrived, and the raw ``counts``."""

    t_device: float
    t_host: float
    counts: int


class ADC(ABC):
    """A stream of force-sensor samples. Subclasses implement ``start``, ``read`` and ``stop``."""

    name = "pressure ADC"
    port = "?"
    skipped = 0  # bad lines skipped so far

    @abstractmethod
    def start(self) -> None:
        """Ask the device to stream."""

    @abstractmethod
    def read(self) -> Sample:
        """The next valid sample; raises ``SensorStalled`` or ``DeviceDisconnected``."""

    @abstractmethod
    def stop(self) -> None:
        """Ask the device to stop streaming (quietly does nothing if it is gone)."""

    def close(self) -> None:
        """Stop and release the device."""
        self.stop()

    def __enter__(self) -> "ADC":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def checksum(payload: bytes) -> int:
    """XOR of all bytes of ``payload``: the ``HH`` of the line protocol."""
    x = 0
    for b in payload:
        x ^= b
    return x


def format_line(t_us: int, counts: int) -> bytes:
    """One protocol line, as the firmware sends it."""
    payload = f"{t_us % WRAP},{counts}".encode()
    return payload + b"*%02X\n" % checksum(payload)


class SerialADC(ADC):
    """A microcontroller or ADS1115-style ADC speaking line protocol 1 over a serial port.

    Args:
        port: serial port or pyserial URL (``/dev/ttyACM0``, ``COM5``, ``loop://``).
        baudrate: line speed [bit/s] (ignored by USB-CDC devices).
        stall_timeout: longest wait for a valid sample once streaming [s].
        start_timeout: longest wait for the first sample after ``start`` [s] (boards that reset on open).
        counts_range: smallest and largest valid reading (ADS1115: -32768, 32767).
        clock_tolerance: how far a sample may claim to be taken after it arrived [s], beyond 1000 ppm drift.
        max_line: longest accepted line [bytes]; longer runs without a newline are dropped.

    Attributes ``samples`` and ``skipped`` count valid samples and bad lines since ``start``; ``last_skip`` says
    why the latest line was skipped.
    """

    def __init__(self, port: str, *, baudrate: int = 115200, stall_timeout: float = 1.0,
                 start_timeout: float = 3.0, counts_range: tuple[int, int] = (-32768, 32767),
                 clock_tolerance: float = 0.05, max_line: int = 64) -> None:
        self.port, self.stall_timeout, self.start_timeout = port, stall_timeout, start_timeout
        self.counts_range, self.clock_tolerance, self.max_line = tuple(counts_range), clock_tolerance, max_line
        self.samples, self.skipped, self.last_skip = 0, 0, ""
        try:
            self._port = serial.serial_for_url(port, baudrate=baudrate, timeout=0.02)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise HardwareError(f"{self.name}: cannot open serial port {port!r}: {exc}") from exc
        self._reset_stream()

    def _reset_stream(self) -> None:
        self._buffer = bytearray()
        self._lines: collections.deque[tuple[bytes, float]] = collections.deque()
        self._epoch = 0
        self._last_raw: int | None = None
        self._last_t = -float("inf")
        self._first_t: float | None = None
        self._min_lag = float("inf")  # min over accepted samples of t_host - t_device [s]

    def start(self) -> None:
        self._reset_stream()
        self.samples, self.skipped, self.last_skip = 0, 0, ""
        try:
            self._port.reset_input_buffer()
            self._port.write(b"START\n")
        except serial.SerialException as exc:
            raise DeviceDisconnected(f"{self.name} on {self.port}: cannot send START: {exc}") from exc

    def stop(self) -> None:
        try:
            self._port.write(b"STOP\n")
        except (serial.SerialException, OSError):
            pass  # the device is gone; nothing to stop

    def close(self) -> None:
        self.stop()
        self._port.close()

    def read(self) -> Sample:
        timeout = self.stall_timeout if self.samples else self.start_timeout
        deadline = time.monotonic() + timeout
        while True:
            while self._lines:
                sample = self._parse(*self._lines.popleft())
                if sample is not None:
                    self.samples += 1
                    return sample
            if time.monotonic() > deadline:
                raise SensorStalled(self._stall_message(timeout))
            try:
                chunk = self._port.read(max(1, self._port.in_waiting))
            except (serial.SerialException, OSError) as exc:
                raise DeviceDisconnected(f"{self.name} on {self.port}: serial port failed after "
                                         f"{self.samples} samples: {exc}") from exc
            if chunk:
                self._feed(chunk, time.monotonic())

    def _stall_message(self, timeout: float) -> str:
        what = (f"no valid sample for {timeout} s after {self.samples} samples" if self.samples else
                f"no sample within {timeout} s of START: is the firmware speaking line protocol 1?")
        skipped = f"; {self.skipped} lines skipped, latest: {self.last_skip}" if self.skipped else ""
        return f"{self.name} on {self.port}: {what}{skipped}"

    def _feed(self, chunk: bytes, t_host: float) -> None:
        self._buffer += chunk
        *lines, rest = self._buffer.split(b"\n")
        for line in lines:
            if len(line) > self.max_line:
                self._skip(f"line of {len(line)} bytes, longer than {self.max_line}: {bytes(line[:24])!r}...")
            else:
                self._lines.append((bytes(line), t_host))
        self._buffer = bytearray(rest)
        if len(self._buffer) > self.max_line:
            self._skip(f"{len(self._buffer)} bytes without a newline: {bytes(self._buffer[:24])!r}...")
            self._buffer.clear()

    def _skip(self, reason: str) -> None:
        self.skipped += 1
        self.last_skip = reason
        if f"{self.skipped}".strip("0") == "1":  # 1, 10, 100, ...
            warnings.warn(f"{self.name} on {self.port}: skipped {self.skipped} bad line(s); latest: {reason}",
                          HardwareWarning, stacklevel=4)

    def _parse(self, line: bytes, t_host: float) -> Sample | None:
        line = line.rstrip(b"\r")
        if not line or line.startswith(b"#"):
            return None
        payload, star, check = line.partition(b"*")
        try:
            if not star or int(check, 16) != checksum(payload) or len(check) != 2:
                raise ValueError("checksum")
            t_text, counts_text = payload.split(b",")
            t_raw, counts = int(t_text), int(counts_text)
            if not 0 <= t_raw < WRAP:
                raise ValueError("time")
        except ValueError:
            self._skip(f"unreadable line {line[:40]!r}")
            return None
        if not self.counts_range[0] <= counts <= self.counts_range[1]:
            self._skip(f"counts {counts} outside {self.counts_range}")
            return None
        epoch = self._epoch
        if self._last_raw is not None and t_raw < self._last_raw and self._last_raw - t_raw > WRAP // 2:
            epoch += WRAP
        t_device = (epoch + t_raw) * 1e-6
        if t_device <= self._last_t:
            self._skip(f"device time went back from {self._last_t:.6f} s to {t_device:.6f} s "
                       "(did the device reset?)")
            return None
        if self._first_t is not None:
            allowed = self.clock_tolerance + 1e-3 * (t_device - self._first_t)
            if t_host - t_device < self._min_lag - allowed:
                self._skip(f"device time {t_device:.6f} s is {self._min_lag - (t_host - t_device):.3f} s ahead "
                           "of its arrival (garbled time stamp or device reset)")
                return None
        else:
            self._first_t = t_device
        self._epoch, self._last_raw, self._last_t = epoch, t_raw, t_device
        self._min_lag = min(self._min_lag, t_host - t_device)
        return Sample(t_device, t_host, counts)
