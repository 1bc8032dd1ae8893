"""The ADC driver and line protocol 1: against the emulator on a pseudo-terminal (faults included) and against
hand-written lines on pyserial's loop:// port."""

from __future__ import annotations

import time

import pytest

from diffstir.hardware import DeviceDisconnected, HardwareError, HardwareWarning, SensorStalled, SerialADC
from diffstir.hardware.adc import WRAP, checksum, format_line

pytestmark = pytest.mark.timeout(10)


def _read(adc: SerialADC, n: int) -> list:
    return [adc.read() for _ in range(n)]


def _as_sent(samples) -> list[tuple[int, int]]:
    return [(round(s.t_device * 1e6) % WRAP, s.counts) for s in samples]


def test_line_format():
    assert format_line(1234, -5) == b"1234,-5*%02X\n" % checksum(b"1234,-5")
    assert checksum(b"1234,-5") == 0x31 ^ 0x32 ^ 0x33 ^ 0x34 ^ 0x2C ^ 0x2D ^ 0x35


def test_clean_stream_is_received_exactly(adc_emulator):
    emulator = adc_emulator(sample_rate=500)
    with SerialADC(emulator.port) as adc:
        adc.start()
        samples = _read(adc, 200)
    assert _as_sent(samples) == emulator.sent[:200]
    assert adc.skipped == 0
    assert all(b.t_device - a.t_device == pytest.approx(2e-3) for a, b in zip(samples, samples[1:]))
    assert all(s.t_host >= s.t_device + samples[0].t_host - samples[0].t_device - 0.05 for s in samples)


def test_garbage_and_partial_lines_are_skipped_and_counted(adc_emulator):
    emulator = adc_emulator(sample_rate=500, garbage_every=20, partial_every=33)
    with SerialADC(emulator.port) as adc, pytest.warns(HardwareWarning) as caught:
        adc.start()
        samples = _read(adc, 300)
    assert _as_sent(samples) == emulator.sent[:300]  # every good line, in order, nothing invented
    lost = emulator.emitted - len(emulator.sent)
    assert adc.skipped >= lost  # each cut line costs itself and the line it merged with, counted once per line
    counts = [int(str(w.message).split("skipped ")[1].split()[0]) for w in caught]
    assert counts[:2] == [1, 10]  # a warning at the 1st, 10th, 100th... skip


def test_stall_raises_with_port_and_counts(adc_emulator):
    emulator = adc_emulator(sample_rate=500, stall_after=50)
    with SerialADC(emulator.port, stall_timeout=0.2) as adc:
        adc.start()
        assert len(_read(adc, 50)) == 50
        t0 = time.monotonic()
        with pytest.raises(SensorStalled, match=rf"{emulator.port}: no valid sample for 0.2 s after 50 samples"):
            adc.read()
        assert 0.15 < time.monotonic() - t0 < 1.5


def test_silent_device_after_start(adc_emulator):
    emulator = adc_emulator(stall_after=0)
    with SerialADC(emulator.port, start_timeout=0.2) as adc:
        adc.start()
        with pytest.raises(SensorStalled, match="no sample within 0.2 s of START"):
            adc.read()


def test_device_disappearing_raises_after_everything_sent(adc_emulator):
    emulator = adc_emulator(sample_rate=500, disappear_after=120)
    with SerialADC(emulator.port) as adc:
        adc.start()
        samples = []
        with pytest.raises(DeviceDisconnected, match=rf"{emulator.port}: serial port failed after 120 samples"):
            while True:
                samples.append(adc.read())
    assert _as_sent(samples) == emulator.sent


def test_device_clock_wrap_is_unwrapped(adc_emulator):
    emulator = adc_emulator(sample_rate=500, clock_start=WRAP * 1e-6 - 0.1)
    with SerialADC(emulator.port) as adc:
        adc.start()
        samples = _read(adc, 150)
    times = [s.t_device for s in samples]
    assert times[0] < WRAP * 1e-6 < times[-1]
    assert all(b - a == pytest.approx(2e-3) for a, b in zip(times, times[1:]))
    assert adc.skipped == 0


def test_missing_port_names_it():
    with pytest.raises(HardwareError, match="cannot open serial port '/dev/diffstir-no-such-port'"):
        SerialADC("/dev/diffstir-no-such-port")


def _loop_adc(lines: list[bytes], **kwargs) -> SerialADC:
    """A driver on loop:// reading ``lines`` (its own START, looped back, is taken out first)."""
    adc = SerialADC("loop://", **kwargs)
    adc.start()
    assert adc._port.read(6) == b"START\n"
    adc._port.write(b"".join(lines))
    return adc


@pytest.mark.filterwarnings("ignore::diffstir.hardware.HardwareWarning")
@pytest.mark.parametrize("bad, reason", [
    (b"1500,7*00\n", "unreadable line"),                    # wrong checksum
    (b"1500,7\n", "unreadable line"),                       # no checksum
    (format_line(1500, 40000), "counts 40000 outside"),     # beyond a 16-bit ADC
    (format_line(900, 7), "device time went back"),         # device reset
    (format_line(5_000_000, 7), "ahead of its arrival"),    # time stamp 5 s in the future
    (b"x" * 80 + b"\n", "longer than 64"),                  # runaway line
])
def test_bad_lines_are_skipped_with_a_reason(bad, reason):
    adc = _loop_adc([b"# hello\r\n", format_line(1000, 5), bad, format_line(2000, 6)], stall_timeout=0.2)
    try:
        first, second = adc.read(), adc.read()
    finally:
        adc.close()
    assert (first.counts, second.counts, second.t_device) == (5, 6, 2000e-6)
    assert adc.skipped == 1 and reason in adc.last_skip


def test_carriage_returns_are_accepted():
    adc = _loop_adc([format_line(10, 1).replace(b"\n", b"\r\n")])
    try:
        assert adc.read().counts == 1
    finally:
        adc.close()
