#!/usr/bin/env python3
"""A stranger on a head's port: a plain Zenoh peer (eclipse-zenoh, not
rotorhive's link) that connects to a live `hive train --listen` head, finds
its run, and sends it malformed, out-of-range, NaN, forged and oversized
messages at a given rate, the way a hostile or broken peer would.

    python scripts/stranger.py --connect tcp/127.0.0.1:7447 --rate 1000 --seconds 30

It finds the head's run, waits --after seconds (for worker slot 1 to
join), then sends for --seconds and
prints one JSON line: how many messages it sent on slot 1's keys (each
must be counted in that host's `rejected_messages` in `summary.json`), how
many on keys of a slot that no host holds (counted on the head's row), and
how many oversized ones Zenoh itself drops (counted nowhere), and both
counts by the reason the head must give (`slot_by_reason`,
`unknown_by_reason`: each must equal that host's `rejected_by_reason`).
Every message it sends is one an honest worker never sends.
"""

import argparse
import json
import math
import struct
import sys
import time

import zenoh

DEPTH_WORDS = 2 * 2 * 32 * 32  # two observations of two 32 × 32 frames, u16
SCALARS = 11  # velocities of s and s', action, reward, done, expert label, demonstration flag
TRANSITION_BYTES = 2 * DEPTH_WORDS + 4 * SCALARS


def transition(action=1.0, reward=3.0, done=0.0, expert=-1.0, demo=0.0):
    # msg::TAIL: action, reward, done, the teacher's label (-1: none), the
    # demonstration flag (0: the student flew it).
    depth = b"\x00\x80" * DEPTH_WORDS
    return depth + struct.pack("<11f", 0.1, 0.2, 0.3, 0.1, 0.2, 0.3, action, reward, done, expert, demo)


def trans_header(actor, count, seq=0, epoch=0):
    # TransitionHeader: actor, count, seq, weight_version (24 bytes); then
    # the link's LinkHeader: epoch, seq in the stream (16 bytes). The head
    # gives each join its epoch (random): a forged one is not the worker's.
    return struct.pack("<IIQQ", actor, count, seq, 0) + struct.pack("<QQ", epoch, seq)


def ep_header(actor, count):
    # EpisodeHeader: actor, count, epsilon_micro, step (24 bytes).
    return struct.pack("<IIQQ", actor, count, 100_000, 0)


def telemetry(role, index, work=0):
    head = struct.pack("<IIII", role, index, 0, 0)
    counters = struct.pack("<QQQQQq", 1, work, 0, 0, 0, 0)
    stages = struct.pack("<4Q", 0, 0, 0, 0)
    learning = struct.pack("<fffIffII", 0, 0, 0, 0, 0, 0, 0, 0)
    delivery = struct.pack("<4Q", 0, 0, 0, 0)
    teacher = struct.pack("<6Q", 0, 0, 0, 0, 0, 0)
    return head + counters + stages + learning + delivery + teacher


def forged(slot_env):
    """(key suffix, payload, attachment, reason) of every kind, for slot 1
    whose first environment is `slot_env`; the reason is the one the head
    must count it under (`summary.json`'s `rejected_by_reason`)."""
    a = slot_env
    return [
        ("host/1/transitions", transition() + b"\x00", trans_header(a, 1), "length"),  # odd length
        ("host/1/transitions", transition(reward=math.nan), trans_header(a, 1), "values"),  # NaN reward
        ("host/1/transitions", transition(action=2.0), trans_header(a, 1), "values"),  # action out of range
        ("host/1/transitions", transition(done=0.5), trans_header(a, 1), "values"),  # done flag out of range
        ("host/1/transitions", transition(expert=5.0), trans_header(a, 1), "values"),  # label out of range
        ("host/1/transitions", transition(demo=0.5), trans_header(a, 1), "values"),  # demonstration flag out of range
        ("host/1/transitions", transition(), trans_header(0, 1), "environment"),  # the head's environment
        ("host/1/transitions", transition(), trans_header(a + 1000, 1), "environment"),  # nobody's environment
        ("host/1/transitions", transition() * 2, trans_header(a, 1), "length"),  # count says 1, payload holds 2
        ("host/1/transitions", b"", trans_header(a, 0), "count"),  # count 0
        ("host/1/transitions", transition(), trans_header(a, 1)[:-1], "header"),  # short header
        ("host/1/transitions", transition(), None, "header"),  # no header
        ("host/1/transitions", transition(), trans_header(a, 1)[:24], "header"),  # no link header
        ("host/1/transitions", transition(), trans_header(a, 1, epoch=12345), "epoch"),  # well formed, a forged epoch
        ("host/1/episodes", b"\x00" * 13, ep_header(a, 1), "length"),  # not whole floats
        ("host/1/episodes", struct.pack("<4f", math.nan, 10, 1, 0.1), ep_header(a, 1), "values"),  # NaN return
        ("host/1/episodes", struct.pack("<4f", 1e9, 10, 7, 0.1), ep_header(a, 1), "values"),  # done code 7
        ("host/1/episodes", struct.pack("<4f", 450, 150, 2, 0.1), ep_header(0, 1), "environment"),  # the head's environment
        ("host/1/episodes", struct.pack("<4f", 450, 150, 2, 0.1), ep_header(a, 2), "length"),  # count says 2
        ("host/1/telemetry", b"", telemetry(3, 0), "role"),  # a learner: no worker runs one
        ("host/1/telemetry", b"", telemetry(0, 0, work=10**15), "role"),  # the head's sim
        ("host/1/telemetry", b"", telemetry(4, 2), "role"),  # another slot's link
        ("host/1/telemetry", b"x", telemetry(0, a), "length"),  # a payload where none goes
    ]


def unknown_slot(slot_env):
    return [
        ("host/9/transitions", transition(), trans_header(slot_env, 1), "slot"),
        ("host/9/episodes", struct.pack("<4f", 450, 150, 2, 0.1), ep_header(slot_env, 1), "slot"),
        ("host/9/telemetry", b"", telemetry(0, slot_env, work=10**15), "slot"),
    ]


def find_run(session, deadline):
    """The run's name, from the head's liveliness token (a peer sees only
    the head's own tokens, not those of the workers joined to it)."""
    while time.time() < deadline:
        for r in session.liveliness().get("rotorhive/**", timeout=2.0):
            if r.ok is not None:
                key = str(r.ok.key_expr)
                if key.endswith("/head"):
                    return key.split("/")[1]
        time.sleep(0.2)
    raise SystemExit("no head found on the port")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--connect", required=True, help="the head's endpoint, tcp/ADDR:PORT")
    p.add_argument("--rate", type=float, default=1000.0, help="messages per second")
    p.add_argument("--seconds", type=float, default=30.0)
    p.add_argument("--slot-env", type=int, default=1, help="slot 1's first environment (the head's envs)")
    p.add_argument("--oversized", type=int, default=1, help="messages above the head's size limit, sent last")
    p.add_argument("--wait", type=float, default=60.0, help="seconds to wait for the head")
    p.add_argument("--after", type=float, default=5.0, help="seconds between finding the head and the first message (its worker joins meanwhile)")
    a = p.parse_args()

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([a.connect]))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    session = zenoh.open(conf)
    run = find_run(session, time.time() + a.wait)
    time.sleep(a.after)
    block = zenoh.CongestionControl.BLOCK
    bad, stray = forged(a.slot_env), unknown_slot(a.slot_env)
    kinds = [(m, "slot") for m in bad] + [(m, "unknown") for m in stray]
    sent = {"slot": 0, "unknown": 0, "oversized": 0}
    reasons = {"slot": {}, "unknown": {}}
    start = time.time()
    i = 0
    while time.time() - start < a.seconds:
        (key, payload, att, reason), where = kinds[i % len(kinds)]
        session.put(f"rotorhive/{run}/{key}", payload, attachment=att, congestion_control=block)
        sent[where] += 1
        reasons[where][reason] = reasons[where].get(reason, 0) + 1
        i += 1
        # Paced to the rate, in bursts of a millisecond's worth.
        ahead = i / a.rate - (time.time() - start)
        if ahead > 0:
            time.sleep(ahead)
    elapsed = time.time() - start
    for _ in range(a.oversized):
        n = 20 << 20
        session.put(f"rotorhive/{run}/host/1/transitions", b"\x00" * n, attachment=trans_header(a.slot_env, n // TRANSITION_BYTES), congestion_control=block)
        sent["oversized"] += 1
    time.sleep(1.0)
    session.close()
    by_reason = {"slot_by_reason": reasons["slot"], "unknown_by_reason": reasons["unknown"]}
    print(json.dumps({"run": run, "seconds": elapsed, "rate": (sent["slot"] + sent["unknown"]) / elapsed, **sent, **by_reason}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
