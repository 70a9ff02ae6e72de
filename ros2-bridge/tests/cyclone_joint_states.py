"""Reads sensor_msgs/JointState from the DDS topic rt/joint_states with Eclipse Cyclone DDS
(PyPI `cyclonedds`), an independent DDS implementation, and prints each sample as one JSON
line: {"sec", "nanosec", "name", "position"}.

usage: cyclone_joint_states.py DOMAIN COUNT TIMEOUT_S

Run it only inside a private network namespace (DDS discovery multicasts): the bridge's
tests/dds.rs does.
"""

import json
import sys
import time
from dataclasses import dataclass

from cyclonedds.domain import DomainParticipant
from cyclonedds.idl import IdlStruct
from cyclonedds.idl.types import float64, int32, sequence, uint32
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic


@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: int32
    nanosec: uint32


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time
    frame_id: str


@dataclass
class JointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: Header
    name: sequence[str]
    position: sequence[float64]
    velocity: sequence[float64]
    effort: sequence[float64]


def main() -> int:
    domain, count, timeout = int(sys.argv[1]), int(sys.argv[2]), float(sys.argv[3])
    participant = DomainParticipant(domain)
    reader = DataReader(participant, Topic(participant, "rt/joint_states", JointState))
    deadline = time.monotonic() + timeout
    seen = 0
    while seen < count and time.monotonic() < deadline:
        for sample in reader.take(N=32):
            if not isinstance(sample, JointState):
                continue
            print(
                json.dumps(
                    {
                        "sec": sample.header.stamp.sec,
                        "nanosec": sample.header.stamp.nanosec,
                        "name": list(sample.name),
                        "position": list(sample.position),
                    }
                ),
                flush=True,
            )
            seen += 1
        time.sleep(0.005)
    return 0 if seen >= count else 1


if __name__ == "__main__":
    sys.exit(main())
