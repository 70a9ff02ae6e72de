#!/usr/bin/env python3
"""Drives the firmware under QEMU for scripts/qemu-cost/run.sh: warms the path up, then
sends the measured datagrams one at a time, each after a quiet pause, so that each one's
interval in the exec trace (counted by run.sh's awk) stands alone.

Usage: drive.py ARMCTL HOST:PORT COUNTS_FILE REPEATS
Prints "pending: <counts...>" and "stopped: <counts...>".
"""
import hashlib
import os
import socket
import struct
import subprocess
import sys
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "../../tests/scripts"))
from arm_frames import crc8  # noqa: E402

armctl, target, counts_file, repeats = sys.argv[1], sys.argv[2], sys.argv[3], int(sys.argv[4])
host, port = target.rsplit(":", 1)
addr = (host, int(port))
sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
sock.bind(("127.0.0.1", 0))
sock.settimeout(0.5)
seq = 0


def encode(*args):
    """A frame from `armctl frame encode ARGS`, renumbered with the next sequence number."""
    global seq
    hexed = subprocess.run([armctl, "frame", "encode", *args], check=True,
                           capture_output=True, text=True).stdout.strip()
    body = bytearray(bytes.fromhex(hexed)[:-1])
    body[0] = seq
    seq = (seq + 1) % 256
    return bytes(body) + bytes([crc8(body)])


def exchange(frame, what):
    """Sends `frame` until its ACK (tag 0x14... any report whose seq matches) comes back."""
    for _ in range(20):
        sock.sendto(frame, addr)
        deadline = time.time() + 0.5
        while time.time() < deadline:
            try:
                reply, _ = sock.recvfrom(2048)
            except socket.timeout:
                break
            if reply[0] == frame[0]:
                return reply
    sys.exit(f"no reply to {what}")


def intervals():
    """Lines the trace counter has written so far."""
    with open(counts_file) as f:
        return [line.split() for line in f if line.strip()]


def settle():
    # The trace is written through pipes: let it drain, and the firmware go idle.
    time.sleep(1.0)


def measured(frame, what, kind):
    before = len(intervals())
    exchange(frame, what)
    settle()
    new = [int(n) for k, n in intervals()[before:] if k == kind]
    if not new:
        sys.exit(f"{what}: no '{kind}' interval in the trace")
    return new[0]


point = "--point"
moves = [f"{point}", "10000:1,1"]
exchange(encode("status"), "STATUS")
exchange(encode("joints-count", "2"), "JOINTS_COUNT")
exchange(encode("upload-stop"), "UPLOAD_STOP")
exchange(encode("location-setting", "0", "0"), "LOCATION_SETTING")
settle()

# One 12-point PENDING each, NIC interrupt to the ACK leaving the NIC.
pending = []
for r in range(repeats):
    exchange(encode("new", "12"), "NEW")
    args = ["pending", "--from", "0,0"]
    for k in range(12):
        args += [point, f"10000:{k + 1},{k + 1}"]
    settle()
    pending.append(measured(encode(*args), "PENDING", "ack"))
    exchange(encode("stopped"), "STOPPED")

# STOPPED during a slow run, NIC interrupt to the step output stopped.
stopped = []
for r in range(repeats):
    exchange(encode("location-setting", "0", "0"), "LOCATION_SETTING")
    exchange(encode("new", "12"), "NEW")
    args = ["pending", "--from", "0,0"]
    for k in range(12):
        args += [point, f"100000:{10 * (k + 1)},{10 * (k + 1)}"]
    exchange(encode(*args), "PENDING")
    exchange(encode("runing"), "RUNING")
    time.sleep(0.5)
    stopped.append(measured(encode("stopped"), "STOPPED", "stop"))

# Authentication (issue 21, docs/PROTOCOL.md section 13): the same 12-point PENDING in an
# envelope (keyed BLAKE2s-128 over the epoch and the envelope), NIC interrupt to the sealed
# ACK leaving the NIC: the envelope's cost is the difference.
KEY = bytes(range(32))


def raw(tag, data=b""):
    global seq
    body = bytes([seq, tag]) + data
    seq = (seq + 1) % 256
    return body + bytes([crc8(body)])


def mac(direction, epoch, signed):
    return hashlib.blake2s(struct.pack("<Q", epoch) + signed, digest_size=16, key=KEY,
                           person=direction).digest()


session = None


def seal(inner):
    global session
    epoch, sid, counter = session
    session = (epoch, sid, counter + 1)
    signed = bytes([inner[0], 0x50]) + struct.pack("<IQ", sid, counter + 1) + inner
    body = signed + mac(b"armH2C01", epoch, signed)
    return body + bytes([crc8(body)])


exchange(raw(0x52, KEY), "SET_KEY")
nonce = os.urandom(16)
reply = exchange(raw(0x51, nonce), "HELLO")
inner = reply[14:-17]
if len(reply) < 31 or reply[1] != 0x50 or inner[1] != 0x53 or inner[2:18] != nonce:
    sys.exit(f"no HELLO_REPLY: {reply.hex()}")
epoch, sid = struct.unpack("<QI", inner[18:30])
if mac(b"armC2H01", epoch, reply[:-17]) != reply[-17:-1]:
    sys.exit("HELLO_REPLY's MAC does not verify: the Rust and Python BLAKE2s disagree")
session = (epoch, sid, 0)
authenticated = []
for r in range(repeats):
    exchange(seal(encode("location-setting", "0", "0")), "LOCATION_SETTING")
    exchange(seal(encode("new", "12")), "NEW")
    args = ["pending", "--from", "0,0"]
    for k in range(12):
        args += [point, f"10000:{k + 1},{k + 1}"]
    settle()
    authenticated.append(measured(seal(encode(*args)), "authenticated PENDING", "ack"))
    exchange(encode("stopped"), "STOPPED")
# Clear the key again (sealed SET_KEY with no data).
exchange(seal(raw(0x52)), "SET_KEY clear")

print("pending:", *pending)
print("stopped:", *stopped)
print("authenticated:", *authenticated)
