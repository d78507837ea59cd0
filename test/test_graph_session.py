"""The graph client's comparison of pushed parameters with the running ones (a no-op push must not be waited for)."""
import array

from piezo_ff_ros.ros.graph_session import _same_value


def test_same_value_as_the_compensator_compares():
    assert _same_value(array.array("d", [1.0, 2.0]), [1, 2])     # rclpy returns arrays; configs give lists of ints
    assert _same_value(3, 3.0) and _same_value("a", "a") and _same_value(True, True)
    assert not _same_value([1.0], [1.0, 2.0])
    assert not _same_value(0.5, 0.6)
    assert not _same_value([[1.0, 2.0]], [[1.0, 2.5]])
