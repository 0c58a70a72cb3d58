"""Rig files the tests derive from the shipped hardware/rig.toml."""

from pathlib import Path


def rig_without_run_enable(tmp_path) -> Path:
    """The shipped rig file with the Nano's run-enable out of the kill chain (``[limits] supervisor_timeout_s =
    0``): for what the link itself does across resets, which a wired run-enable turns into an engine cut."""
    src = Path(__file__).resolve().parents[1] / "hardware" / "rig.toml"
    text = src.read_text()
    assert "\nsupervisor_timeout_s = 0.2" in text
    out = Path(tmp_path) / "rig-no-run-enable.toml"
    out.write_text(text.replace("\nsupervisor_timeout_s = 0.2", "\nsupervisor_timeout_s = 0.0"))
    return out
