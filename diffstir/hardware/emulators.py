"""Emulated devices on pseudo-terminals, for the tests and for running the record app without hardware (POSIX).

Each emulator serves the far end of a pty from a thread; a driver opens ``emulator.port`` like any serial port,
so the whole driver, pyserial included, is exercised. Faults can be injected:

- ``ADCEmulator``: garbage lines, partial lines (a line cut short, merging with the next), a stall (the stream
  stops, the port stays), the device disappearing (the pty closes: reads fail as on a pulled USB cable).
- ``AG95Emulator``: replies with a corrupted CRC, no reply at all, a gripper that never reaches its target,
  a rod that is dropped.

``EmulatedADC`` and ``EmulatedAG95`` are the drivers wired to their own emulator: the record app's
``emulated`` backends.
"""

from __future__ import annotations

import fcntl
import math
import os
import select
import struct
import termios
import threading
import time
import tty

import numpy as np

from diffstir.hardware.adc import SerialADC, format_line
from diffstir.hardware.calibration import Calibration, Divider
from diffstir.hardware.errors import HardwareError
from diffstir.hardware.gripper import AG95_REGISTERS, AG95Gripper, GripState, InitState
from diffstir.hardware.modbus import READ_HOLDING_REGISTERS, WRITE_SINGLE_REGISTER, crc_ok, with_crc


def nominal_calibration() -> Calibration:
    """The emulated sensor's true calibration: 3.3 V divider with 10 kohm, ADS1115 at +-4.096 V (125 uV per
    count), F = 5e4 N/S * G + 0.1 N (a thin-film sensor of about 10 kohm at 5 N that starts conducting at 0.1 N)."""
    return Calibration(Divider(3.3, 10e3, 125e-6), 5e4, 0.1, sensor_serial="emulated")


class PtyDevice:
    """A device on the far end of a pseudo-terminal, served by a thread; ``port`` is the name to open."""

    def __init__(self) -> None:
        if os.name != "posix":
            raise HardwareError("emulated devices need POSIX pseudo-terminals (Linux, macOS)")
        self._master, self._slave = os.openpty()
        tty.setraw(self._slave)
        os.set_blocking(self._master, False)
        self.port = os.ttyname(self._slave)
        self._out = bytearray()
        self._stop = threading.Event()
        self._gone = threading.Event()
        self._thread = threading.Thread(target=self._serve, name=f"emulator {self.port}", daemon=True)
        self._thread.start()

    def received(self, data: bytes, now: float) -> None:
        """Bytes the driver sent."""

    def tick(self, now: float) -> None:
        """Called every few milliseconds."""

    def send(self, data: bytes) -> None:
        """Queue bytes for the driver."""
        self._out += data

    def _drain(self) -> None:
        while self._out:
            try:
                n = os.write(self._master, self._out)
            except BlockingIOError:
                return
            del self._out[:n]

    def _serve(self) -> None:
        try:
            while not (self._stop.is_set() or self._gone.is_set()):
                ready, _, _ = select.select([self._master], [], [], 0.002)
                now = time.monotonic()
                if ready:
                    self.received(os.read(self._master, 4096), now)
                self.tick(now)
                self._drain()
        finally:
            os.close(self._master)
            os.close(self._slave)

    def disappear(self) -> None:
        """Vanish like a pulled cable, once the driver has read what was sent: the pty closes."""
        deadline, quiet = time.monotonic() + 1.0, 0
        while time.monotonic() < deadline and quiet < 10:  # 20 ms with nothing left to read
            self._drain()
            quiet = 0 if self._out or self._unread() else quiet + 1
            time.sleep(0.002)
        self._gone.set()

    def _unread(self) -> int:
        return struct.unpack("i", fcntl.ioctl(self._slave, termios.FIONREAD, b"\0\0\0\0"))[0]

    def close(self) -> None:
        """Stop serving and close the pty."""
        self._stop.set()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout=2.0)


class ADCEmulator(PtyDevice):
    """A microcontroller streaming line protocol 1 (``diffstir.hardware.adc``).

    Args:
        sample_rate: samples per second of device time [Hz].
        force: the true force [N] as a function of device time [s]; default a constant 1 N.
        calibration: the sensor's true calibration; default ``nominal_calibration()``.
        noise: standard deviation of the reading [counts].
        seed: random seed of the noise and the garbage.
        clock_start: device clock when the emulator starts [s] (near 4294.967296 s to test the wrap).
        clock_rate: device seconds per host second (1 + drift).
        garbage_every: after every n-th sample, a line of random bytes.
        partial_every: every n-th sample line is cut in half, so it merges with the next (both lost).
        stall_after: stop streaming after this many samples, keeping the port open.
        disappear_after: close the pty after this many valid samples have been read by the driver.

    ``sent`` lists (t_us, counts) of every sample line the driver should accept, in order.
    """

    def __init__(self, *, sample_rate: float = 200.0, force=None, calibration: Calibration | None = None,
                 noise: float = 2.0, seed: int = 0, clock_start: float = 0.0, clock_rate: float = 1.0,
                 garbage_every: int | None = None, partial_every: int | None = None,
                 stall_after: int | None = None, disappear_after: int | None = None) -> None:
        self.sample_rate, self.noise, self.clock_start, self.clock_rate = sample_rate, noise, clock_start, clock_rate
        self.force = force if force is not None else (lambda t: 1.0)
        self.calibration = calibration if calibration is not None else nominal_calibration()
        self.garbage_every, self.partial_every = garbage_every, partial_every
        self.stall_after, self.disappear_after = stall_after, disappear_after
        self.sent: list[tuple[int, int]] = []
        self.emitted = 0
        self._rng = np.random.default_rng(seed)
        self._commands = bytearray()
        self._streaming = False
        self._merged = False
        self._created = time.monotonic()
        super().__init__()

    def received(self, data: bytes, now: float) -> None:
        self._commands += data
        *lines, rest = self._commands.split(b"\n")
        self._commands = bytearray(rest)
        for line in lines:
            command = line.strip()
            if command == b"START":
                self._streaming, self._t0, self._n = True, now, 0
                self.send(f"# diffstir-adc/1 emulated rate_hz={self.sample_rate:g}\n".encode())
            elif command == b"STOP":
                self._streaming = False

    def tick(self, now: float) -> None:
        if not self._streaming:
            return
        due = math.floor((now - self._t0) * self.sample_rate * self.clock_rate) + 1
        while self._streaming and self._n < due and not self._gone.is_set():
            self._emit(self._n)
            self._n += 1

    def _emit(self, n: int) -> None:
        if self.stall_after is not None and self.emitted >= self.stall_after:
            return
        self.emitted += 1
        t_device = self.clock_start + (self._t0 - self._created) * self.clock_rate + n / self.sample_rate
        counts = float(self.calibration.counts(self.force(t_device))) + self.noise * self._rng.standard_normal()
        full = self.calibration.divider.supply_voltage / self.calibration.divider.volts_per_count
        counts = int(round(min(max(counts, 0.0), full, 32767)))
        t_us = int(round(t_device * 1e6))
        line = format_line(t_us, counts)
        if self.partial_every and n % self.partial_every == self.partial_every - 1:
            self.send(line[:len(line) // 2])
            self._merged = True
        elif self._merged:
            self.send(line)
            self._merged = False
        else:
            self.send(line)
            self.sent.append((t_us % 2**32, counts))
        if self.garbage_every and n % self.garbage_every == self.garbage_every - 1:
            junk = self._rng.integers(0, 256, 12, dtype=np.uint8).tobytes().replace(b"\n", b"?")
            self.send(junk + b"\n")
            self._merged = False  # a cut line merges with the junk, not with the next sample
        if self.disappear_after is not None and len(self.sent) >= self.disappear_after:
            self.disappear()


class AG95Emulator(PtyDevice):
    """A DH AG-95 answering Modbus-RTU with the register map of ``AG95_REGISTERS``.

    Args:
        slave: Modbus slave id.
        rod_position: opening at which the fingers meet the rod [permille]; None: nothing to catch.
        speed: finger speed [permille of the stroke per s].
        init_time: duration of the initialisation [s].
        crc_errors: the next n replies carry a wrong CRC.
        silent: never reply.
        never_reaches: a commanded motion never ends (grip_state stays MOVING).
    """

    def __init__(self, *, slave: int = 1, rod_position: int | None = 400, speed: float = 5000.0,
                 init_time: float = 0.05, crc_errors: int = 0, silent: bool = False,
                 never_reaches: bool = False) -> None:
        self.slave, self.rod_position, self.speed, self.init_time = slave, rod_position, speed, init_time
        self.crc_errors, self.silent, self.never_reaches = crc_errors, silent, never_reaches
        reg = {name: r.address for name, r in AG95_REGISTERS.items()}
        self._reg = reg
        self.registers = {reg["force"]: 20, reg["position"]: 1000, reg["init_state"]: InitState.NOT_INITIALISED,
                          reg["grip_state"]: GripState.REACHED, reg["position_feedback"]: 1000}
        self.requests = 0
        self._buffer = bytearray()
        self._init_done: float | None = None
        self._last = time.monotonic()
        self._position = 1000.0
        super().__init__()

    def drop(self) -> None:
        """The rod slips out: grip_state becomes DROPPED."""
        self.registers[self._reg["grip_state"]] = GripState.DROPPED

    def received(self, data: bytes, now: float) -> None:
        self._buffer += data
        while len(self._buffer) >= 8:
            frame = bytes(self._buffer[:8])
            if not crc_ok(frame):  # a slave ignores a corrupted frame; resynchronise on the next one
                self._buffer.clear()
                return
            del self._buffer[:8]
            self.requests += 1
            self._reply(self._answer(frame, now))

    def _answer(self, frame: bytes, now: float) -> bytes | None:
        slave, function = frame[0], frame[1]
        address, value = int.from_bytes(frame[2:4], "big"), int.from_bytes(frame[4:6], "big")
        if slave != self.slave:
            return None
        reg = self._reg
        if function == WRITE_SINGLE_REGISTER:
            if address == reg["initialise"] and value in (1, 0xA5):
                self.registers[reg["init_state"]] = InitState.INITIALISING
                self._init_done = now + self.init_time
            elif address == reg["force"] and 20 <= value <= 100:
                self.registers[address] = value
            elif address == reg["position"] and 0 <= value <= 1000:
                self.registers[address] = value
                self.registers[reg["grip_state"]] = GripState.MOVING
            else:
                return self._exception(function, 2 if address not in self.registers and address != reg["initialise"]
                                       else 3)
            return frame[:6]
        if function == READ_HOLDING_REGISTERS:
            addresses = range(address, address + value)
            if not 1 <= value <= 8 or any(a not in self.registers for a in addresses):
                return self._exception(function, 2)
            data = b"".join(int(self.registers[a]).to_bytes(2, "big") for a in addresses)
            return bytes([slave, function, len(data)]) + data
        return self._exception(function, 1)

    def _exception(self, function: int, code: int) -> bytes:
        return bytes([self.slave, function | 0x80, code])

    def _reply(self, payload: bytes | None) -> None:
        if payload is None or self.silent:
            return
        frame = bytearray(with_crc(payload))
        if self.crc_errors > 0:
            self.crc_errors -= 1
            frame[-1] ^= 0xFF
        self.send(bytes(frame))

    def tick(self, now: float) -> None:
        dt, self._last = now - self._last, now
        reg = self._reg
        if self._init_done is not None and now >= self._init_done:
            self._init_done = None
            self.registers[reg["init_state"]] = InitState.INITIALISED
            self.registers[reg["position"]] = 1000
            self._position = 1000.0
            self.registers[reg["grip_state"]] = GripState.REACHED
        if self.registers[reg["grip_state"]] != GripState.MOVING or self.never_reaches:
            return
        target = self.registers[reg["position"]]
        step = math.copysign(min(self.speed * dt, abs(target - self._position)), target - self._position)
        self._position += step
        rod = self.rod_position
        if rod is not None and target < rod and self._position <= rod:
            self._position = rod
            self.registers[reg["grip_state"]] = GripState.CAUGHT
        elif self._position == target:
            self.registers[reg["grip_state"]] = GripState.REACHED
        self.registers[reg["position_feedback"]] = int(round(self._position))


class EmulatedADC(SerialADC):
    """A ``SerialADC`` wired to its own ``ADCEmulator`` whose true force is preload + amplitude sin(2 pi f t)
    [N]; ``calibration`` is the emulated sensor's true calibration.

    Args:
        sample_rate: [Hz]. preload: [N]. amplitude: [N]. frequency: f [Hz]. noise: [counts]. seed: noise seed.
        stall_timeout: as for ``SerialADC`` [s].
        faults: further ``ADCEmulator`` arguments (garbage_every, partial_every, stall_after, disappear_after).
    """

    def __init__(self, *, sample_rate: float = 200.0, preload: float = 1.0, amplitude: float = 0.05,
                 frequency: float = 1.0, noise: float = 2.0, seed: int = 0, stall_timeout: float = 1.0,
                 **faults) -> None:
        self.emulator = ADCEmulator(sample_rate=sample_rate, noise=noise, seed=seed,
                                    force=lambda t: preload + amplitude * math.sin(2 * math.pi * frequency * t),
                                    **faults)
        self.calibration = self.emulator.calibration
        super().__init__(self.emulator.port, stall_timeout=stall_timeout)

    def close(self) -> None:
        super().close()
        self.emulator.close()


class EmulatedAG95(AG95Gripper):
    """An ``AG95Gripper`` wired to its own ``AG95Emulator`` (``emulator`` arguments pass through)."""

    def __init__(self, *, timeout: float = 0.1, retries: int = 3, **emulator) -> None:
        self.emulator = AG95Emulator(**emulator)
        super().__init__(self.emulator.port, timeout=timeout, retries=retries)

    def close(self) -> None:
        super().close()
        self.emulator.close()
