"""The local Milvus's ports: outside the range the kernel hands to outgoing connections, so nothing the
machine does meanwhile takes one between its choice and the server's bind (CI lost a run to that)."""

import random
import socket

from benchmarks.stores.milvus_server import _ephemeral_low, free_port


def test_ports_are_below_the_ephemeral_range_distinct_and_free():
    rng = random.Random(0)
    taken: set[int] = set()
    for _ in range(20):
        port = free_port(rng, frozenset(taken))
        assert port < _ephemeral_low() and port not in taken
        taken.add(port)
        with socket.socket() as s:  # free: it can be bound now
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            s.bind(("127.0.0.1", port))


def test_a_port_in_use_is_never_chosen():
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        busy = held.getsockname()[1]
        rng = random.Random(1)
        # a generator that offers the busy port first: it is skipped
        first = [busy]

        class Offering(random.Random):
            def randint(self, a: int, b: int) -> int:
                return first.pop() if first else rng.randint(a, b)

        assert free_port(Offering(), frozenset()) != busy
