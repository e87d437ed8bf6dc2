"""Tests for one kind of arm: the plugin skips them, saying why, on the others."""

import pytest


@pytest.mark.emulator
async def test_the_emulator_is_behind_the_port(arm):
    assert arm.emulator is not None


@pytest.mark.hardware
async def test_the_lab_arm_answers_on_its_port(arm):
    assert arm.frames_received > 0


@pytest.mark.armbench_target("fake")
def test_fake_only(arm_port):
    assert arm_port.startswith("fake://")
