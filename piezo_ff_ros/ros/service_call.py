"""One service call that survives a lost first reply.

Right after a node starts, ``wait_for_service`` can report a server whose *request* reader has matched this client
while its *reply* writer has not yet matched this client's reply reader.  The server then answers into the void
(Fast DDS waits ``max_blocking_time``, 100 ms by default, for that match; on a loaded machine discovery takes longer)
and the caller waits forever.  A read-only request can simply be asked again; a request that changes something is
sent once, as before.
"""
from __future__ import annotations

import time
from typing import Any, Callable

#: services whose requests change nothing, so asking again after a lost reply is harmless
READ_ONLY_SERVICES = frozenset({
    "rcl_interfaces/GetParameters", "rcl_interfaces/ListParameters", "rcl_interfaces/DescribeParameters",
    "rcl_interfaces/GetParameterTypes", "lifecycle_msgs/GetState", "lifecycle_msgs/GetAvailableStates",
    "lifecycle_msgs/GetAvailableTransitions",
})

#: how long a read-only request waits for its reply before it is asked again [s]
RESEND_EVERY = 2.0


def is_read_only(srv_type: Any) -> bool:
    """Whether ``srv_type`` (a generated service class, e.g. ``GetParameters``) only reads."""
    return f"{srv_type.__module__.split('.')[0]}/{srv_type.__name__}" in READ_ONLY_SERVICES


def call_service(client: Any, request: Any, spin_once: Callable[[float], object], timeout: float,
                 resend_every: float | None = None) -> Any:
    """The reply of ``client`` to ``request`` within ``timeout`` seconds.

    Parameters
    ----------
    client : rclpy.client.Client
        A client whose server is already available (``wait_for_service`` returned true).
    request : Any
        The request message.
    spin_once : callable
        Spins the client's executor once, given a timeout in seconds.
    timeout : float
        Total time to wait for a reply [s].
    resend_every : float, optional
        Ask again after this many seconds without a reply.  Default: :data:`RESEND_EVERY` for a read-only service
        (:func:`is_read_only`), never for any other.

    Returns
    -------
    Any
        The reply message.

    Raises
    ------
    TimeoutError
        No reply within ``timeout`` seconds.
    """
    if resend_every is None and is_read_only(client.srv_type):
        resend_every = RESEND_EVERY
    deadline = time.monotonic() + timeout
    while True:
        fut = client.call_async(request)
        ask_again = deadline if resend_every is None else min(deadline, time.monotonic() + resend_every)
        while not fut.done() and time.monotonic() < ask_again:
            spin_once(0.02)
        if fut.done():
            return fut.result()
        client.remove_pending_request(fut)
        if time.monotonic() >= deadline:
            raise TimeoutError(f"no reply from {client.srv_name} within {timeout:g} s")
