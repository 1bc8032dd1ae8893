"""A minimal Modbus-RTU master on pyserial: CRC-16/MODBUS, two functions, timeouts and retries.

An RTU frame is ``[slave, function, data..., crc_lo, crc_hi]``; the CRC is CRC-16/MODBUS (reflected polynomial
0xA001, initial value 0xFFFF, no final xor) over all bytes before it, sent low byte first (Modbus over Serial
Line V1.02, section 2.5.1.2). Only the two functions the gripper needs are implemented:
0x03 read holding registers and 0x06 write single register (Modbus Application Protocol V1.1b3, 6.3 and 6.6).

A transaction is retried on a timeout, a CRC error or a malformed reply, ``retries`` times, then a
``ModbusError`` names the port, slave, function, register and every failed attempt. An exception reply (a valid
frame with function | 0x80) is a definite answer and is not retried.
"""

from __future__ import annotations

import time

import serial

from diffstir.hardware.errors import DeviceDisconnected, HardwareError, ModbusError

READ_HOLDING_REGISTERS = 0x03
WRITE_SINGLE_REGISTER = 0x06
EXCEPTION_CODES = {
    1: "illegal function", 2: "illegal data address", 3: "illegal data value", 4: "slave device failure",
    5: "acknowledge", 6: "slave device busy",
}


def crc16(data: bytes) -> int:
    """CRC-16/MODBUS of ``data``: shift right, xor 0xA001 when the dropped bit is 1, starting from 0xFFFF."""
    crc = 0xFFFF
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def with_crc(payload: bytes) -> bytes:
    """``payload`` followed by its CRC, low byte first: a complete RTU frame."""
    return bytes(payload) + crc16(payload).to_bytes(2, "little")


def crc_ok(frame: bytes) -> bool:
    """Whether the last two bytes of ``frame`` are the CRC of the bytes before them."""
    return len(frame) >= 3 and crc16(frame[:-2]) == int.from_bytes(frame[-2:], "little")


class _BadReply(Exception):
    """One failed attempt (timeout, CRC error, malformed reply); the transaction may be retried."""


class ModbusRTU:
    """Modbus-RTU master on one serial line (RS-485 adapter).

    Args:
        url: serial port name or pyserial URL (``/dev/ttyUSB0``, ``COM4``, ``loop://``).
        baudrate: line speed [bit/s]; 8 data bits, no parity, 1 stop bit.
        timeout: time allowed for one complete reply [s].
        retries: further attempts after a timeout, CRC error or malformed reply.
        name: the device's name in error messages.
    """

    def __init__(self, url: str, *, baudrate: int = 115200, timeout: float = 0.2, retries: int = 3,
                 name: str = "Modbus device") -> None:
        self.url, self.timeout, self.retries, self.name = url, timeout, retries, name
        try:
            self._port = serial.serial_for_url(url, baudrate=baudrate, timeout=0.01)
        except (serial.SerialException, OSError, ValueError) as exc:
            raise HardwareError(f"{name}: cannot open serial port {url!r}: {exc}") from exc

    def close(self) -> None:
        """Close the serial port."""
        self._port.close()

    def read_registers(self, slave: int, address: int, count: int = 1) -> list[int]:
        """Read ``count`` holding registers from ``address`` (function 0x03); unsigned 16-bit values."""
        body = address.to_bytes(2, "big") + count.to_bytes(2, "big")
        reply = self._transact(slave, READ_HOLDING_REGISTERS, body, address)
        if reply[2] != 2 * count:
            raise ModbusError(f"{self._where(slave, READ_HOLDING_REGISTERS, address)}: asked for {count} "
                              f"registers, the reply holds {reply[2]} bytes")
        return [int.from_bytes(reply[3 + 2 * i:5 + 2 * i], "big") for i in range(count)]

    def write_register(self, slave: int, address: int, value: int) -> None:
        """Write one holding register (function 0x06); the slave echoes the request."""
        if not 0 <= value <= 0xFFFF:
            raise ValueError(f"{self.name}: register 0x{address:04X} value {value} is not a 16-bit unsigned int")
        body = address.to_bytes(2, "big") + value.to_bytes(2, "big")
        self._transact(slave, WRITE_SINGLE_REGISTER, body, address)

    def _where(self, slave: int, function: int, address: int) -> str:
        return f"{self.name} on {self.url}: slave {slave}, function 0x{function:02X}, register 0x{address:04X}"

    def _transact(self, slave: int, function: int, body: bytes, address: int) -> bytes:
        request = with_crc(bytes([slave, function]) + body)
        failures = []
        for _ in range(1 + self.retries):
            try:
                self._port.reset_input_buffer()
                self._port.write(request)
                reply = self._read_reply(slave, function)
            except serial.SerialException as exc:
                raise DeviceDisconnected(f"{self._where(slave, function, address)}: serial port failed: {exc}") \
                    from exc
            except _BadReply as exc:
                failures.append(str(exc))
                time.sleep(0.01)  # let the rest of a garbled reply arrive, then drop it
                continue
            if reply[1] == function | 0x80:
                code = reply[2]
                raise ModbusError(f"{self._where(slave, function, address)}: exception reply {code} "
                                  f"({EXCEPTION_CODES.get(code, 'unknown code')})")
            if function == WRITE_SINGLE_REGISTER and reply != request:
                failures.append(f"write not echoed: sent {request.hex(' ')}, got {reply.hex(' ')}")
                continue
            return reply
        raise ModbusError(f"{self._where(slave, function, address)}: no valid reply in {1 + self.retries} "
                          f"attempts: " + "; ".join(failures))

    def _read_reply(self, slave: int, function: int) -> bytes:
        deadline = time.monotonic() + self.timeout
        head = self._read_exact(3, deadline, b"")
        if head[0] != slave or head[1] not in (function, function | 0x80):
            raise _BadReply(f"reply starts with {head.hex(' ')}, expected slave {slave:02x} function {function:02x}")
        if head[1] & 0x80:
            length = 5
        elif function == READ_HOLDING_REGISTERS:
            length = 5 + head[2]
        else:
            length = 8
        frame = self._read_exact(length, deadline, head)
        if not crc_ok(frame):
            raise _BadReply(f"CRC error in reply {frame.hex(' ')}")
        return frame

    def _read_exact(self, n: int, deadline: float, got: bytes) -> bytes:
        buf = bytearray(got)
        while len(buf) < n:
            if time.monotonic() > deadline:
                what = f"got {bytes(buf).hex(' ')}" if buf else "got nothing"
                raise _BadReply(f"timeout after {self.timeout} s waiting for {n} bytes, {what}")
            buf += self._port.read(n - len(buf))
        return bytes(buf)
