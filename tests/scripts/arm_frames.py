"""Frame checks for the Python clients of the test scripts (sim-host/tests/tap.sh,
scripts/qemu-cost/drive.py): written apart from the Rust protocol crate on purpose, so that
they check it from outside."""


def crc8(data):
    """CRC-8/SMBUS (polynomial 0x07), the protocol's frame check."""
    crc = 0
    for byte in data:
        crc ^= byte
        for _ in range(8):
            crc = ((crc << 1) ^ 0x07) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
    return crc
