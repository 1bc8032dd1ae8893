"""Smoke tests on real devices, skipped unless their port is configured:

    DIFFSTIR_ADC_PORT=/dev/ttyACM0 DIFFSTIR_GRIPPER_PORT=/dev/ttyUSB0 python3 -m pytest tests/hardware -m hardware

The gripper test initialises the AG-95 (its fingers move) and leaves it open; nothing may be between them.
"""

from __future__ import annotations

import os

import numpy as np
import pytest

from diffstir.hardware import AG95Gripper, GripState, InitState, SerialADC, align_clocks

ADC_PORT = os.environ.get("DIFFSTIR_ADC_PORT")
GRIPPER_PORT = os.environ.get("DIFFSTIR_GRIPPER_PORT")


@pytest.mark.hardware
@pytest.mark.timeout(20)
@pytest.mark.skipif(not ADC_PORT, reason="set DIFFSTIR_ADC_PORT to the pressure ADC's serial port")
def test_real_adc_streams_protocol_1():
    with SerialADC(ADC_PORT) as adc:
        adc.start()
        samples = [adc.read() for _ in range(400)]
    t_device = np.array([s.t_device for s in samples])
    assert np.all(np.diff(t_device) > 0) and adc.skipped == 0
    fit = align_clocks(t_device, [s.t_host for s in samples])
    assert abs(fit.rate - 1) < 1e-3  # a crystal clock: drift far below 1000 ppm


@pytest.mark.hardware
@pytest.mark.timeout(30)
@pytest.mark.skipif(not GRIPPER_PORT, reason="set DIFFSTIR_GRIPPER_PORT to the AG-95's RS-485 adapter")
def test_real_gripper_initialises_and_opens():
    with AG95Gripper(GRIPPER_PORT) as gripper:
        gripper.initialise(timeout=15.0)
        gripper.set_force(20)
        status = gripper.open(timeout=5.0)
    assert status.init is InitState.INITIALISED and status.grip is GripState.REACHED and status.position > 900
