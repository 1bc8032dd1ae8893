"""Shared pieces of the hardware tests: the paper's rig as the recording states it, and emulated devices that
are always closed."""

from __future__ import annotations

import pytest

from diffstir.hardware.emulators import ADCEmulator, AG95Emulator
from diffstir.recording import CupGeometry, RodGeometry, SensorSpec


@pytest.fixture
def rig():
    """Cup, rod and sensor of the paper's setup (8.5 cm cup with 738 ml, 2.5 cm rod immersed 8 cm)."""
    return dict(cup=CupGeometry(0.0425, fill_volume=738e-6), rod=RodGeometry(0.0125, 0.080),
                sensor=SensorSpec("component", axis=(1.0, 0.0), resolution=0.005, sample_rate=400))


@pytest.fixture
def adc_emulator():
    """Factory of ADC emulators, closed after the test."""
    made = []

    def make(**kwargs) -> ADCEmulator:
        made.append(ADCEmulator(**kwargs))
        return made[-1]

    yield make
    for emulator in made:
        emulator.close()


@pytest.fixture
def gripper_emulator():
    """Factory of AG-95 emulators, closed after the test."""
    made = []

    def make(**kwargs) -> AG95Emulator:
        made.append(AG95Emulator(**kwargs))
        return made[-1]

    yield make
    for emulator in made:
        emulator.close()
