"""A service reply lost right after a server starts: a read-only request is asked again and answered; a request that
changes something is sent once and times out in one line."""
import pytest

rclpy = pytest.importorskip("rclpy")


class _ServerThatLosesItsFirstReply:
    """A real rclpy service whose first request is never answered (its reply is "lost"); later ones are."""

    def __init__(self, node, srv_type, name):
        from rclpy.task import Future

        self.requests = 0
        self._never = Future()

        async def answer(request, response):
            self.requests += 1
            if self.requests == 1:
                await self._never          # the first reply never leaves the server
            return response

        from rclpy.callback_groups import ReentrantCallbackGroup

        # reentrant: the pending first request must not hold the executor's other callbacks back
        self.service = node.create_service(srv_type, name, answer, callback_group=ReentrantCallbackGroup())


@pytest.fixture
def graph():
    from rclpy.context import Context
    from rclpy.executors import SingleThreadedExecutor

    ctx = Context()
    rclpy.init(context=ctx)
    node = rclpy.create_node("service_call_test", context=ctx)
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    yield node, ex
    ex.shutdown()
    node.destroy_node()
    rclpy.try_shutdown(context=ctx)


def test_a_read_only_request_whose_reply_is_lost_is_asked_again(graph):
    from rcl_interfaces.srv import GetParameters

    from piezo_ff_ros.ros.service_call import call_service, is_read_only

    node, ex = graph
    server = _ServerThatLosesItsFirstReply(node, GetParameters, "/lossy/get_parameters")
    client = node.create_client(GetParameters, "/lossy/get_parameters")
    assert client.wait_for_service(timeout_sec=10)
    assert is_read_only(GetParameters)
    reply = call_service(client, GetParameters.Request(names=["x"]),
                         lambda t: ex.spin_once(timeout_sec=t), timeout=30, resend_every=0.5)
    assert isinstance(reply, GetParameters.Response)
    assert server.requests == 2


def test_a_request_that_changes_something_is_sent_once(graph):
    from rcl_interfaces.srv import SetParameters

    from piezo_ff_ros.ros.service_call import call_service, is_read_only

    node, ex = graph
    server = _ServerThatLosesItsFirstReply(node, SetParameters, "/lossy/set_parameters")
    client = node.create_client(SetParameters, "/lossy/set_parameters")
    assert client.wait_for_service(timeout_sec=10)
    assert not is_read_only(SetParameters)
    with pytest.raises(TimeoutError, match=r"^no reply from /lossy/set_parameters within 1 s$"):
        call_service(client, SetParameters.Request(), lambda t: ex.spin_once(timeout_sec=t), timeout=1)
    assert server.requests == 1


def test_the_package_and_test_callers_go_through_it():
    """Every place that calls a service and waits for its reply uses call_service (so a lost reply of a read-only
    request is asked again everywhere)."""
    import inspect

    from piezo_ff_ros.ros import graph_session, helpers

    import test_nodes_integration

    for fn in (helpers.Session.call, graph_session.GraphClient.call, graph_session.step_lifecycle,
               test_nodes_integration.Probe.call):
        assert "call_service(" in inspect.getsource(fn), fn.__qualname__
