"""Node parameters with one fixed type each, and the refusal of overrides no node declares (rclpy's public API only).

:class:`TypedParameters` declares a node's parameters.  Each keeps the type of its default (or the one given, for an
empty list); a value of another type is refused naming the parameter (``block_size: expected an integer, got a
double 2.5 (kept: 200)``), except where nothing is lost: an integer where a double is declared
(``-p sample_rate:=25000``, ``ros2 param set … ack_timeout 5``) is taken as that double, an integer array as a
double array, an empty array of any type as the declared array type.  rclpy offers this through public hooks
only: the parameters are declared with ``dynamic_typing`` (rclpy itself checks no type), an on-set callback checks
the declared type, a pre-set callback converts the lossless cases of a runtime change, and a declaration whose
override needed a conversion is set once more with the converted value (read-only parameters keep the override as
given; :meth:`TypedParameters.declare` returns the converted value either way).

:func:`refuse_unknown_parameters` is the one call a node makes once its parameters are declared (before it opens a
device or a file): an override it does not declare — ``-p name:=value`` or ``--param`` on the command line, or a
``--params-file`` entry for this node or for every node (``/**``) — stops it with one line naming the parameter and
the closest declared name::

    driver: error: unknown parameter 'limits.voltag' (did you mean 'limits.voltage'?)

rclpy keeps the overrides it parsed to itself, so they are read here from the command line, as rcl reads them:
``--ros-args`` sections (up to ``--``), a ``node:`` prefix that names another node ignored, parameter files through
rclpy's :func:`rclpy.parameter.parameter_dict_from_yaml_file`.
"""
from __future__ import annotations

import copy
import difflib
import sys
from typing import Any, Sequence

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, SetParametersResult
from rclpy.exceptions import InvalidParameterValueException
from rclpy.node import Node
from rclpy.parameter import Parameter, parameter_dict_from_yaml_file

__all__ = ["TypedParameters", "UnknownParameterError", "ParameterRefused", "override_names",
           "refuse_unknown_parameters"]

_TYPE_NAMES = {Parameter.Type.NOT_SET: "nothing", Parameter.Type.BOOL: "a bool", Parameter.Type.INTEGER: "an integer",
               Parameter.Type.DOUBLE: "a double", Parameter.Type.STRING: "a string",
               Parameter.Type.BYTE_ARRAY: "a byte array", Parameter.Type.BOOL_ARRAY: "a bool array",
               Parameter.Type.INTEGER_ARRAY: "an integer array", Parameter.Type.DOUBLE_ARRAY: "a double array",
               Parameter.Type.STRING_ARRAY: "a string array"}
_ARRAY_TYPES = (Parameter.Type.BYTE_ARRAY, Parameter.Type.BOOL_ARRAY, Parameter.Type.INTEGER_ARRAY,
                Parameter.Type.DOUBLE_ARRAY, Parameter.Type.STRING_ARRAY)
#: integers beyond this lose digits as doubles: not converted
_EXACT_INT = 2 ** 53


class UnknownParameterError(ValueError):
    """An override names a parameter the node does not declare (the text names it and the closest declared one)."""


class ParameterRefused(ValueError):
    """An override was refused at its declaration (the text is the refusal's reason, naming the parameter)."""


def _as_python(value: Any) -> Any:
    """A parameter value as plain Python (rclpy returns arrays as ``array.array``)."""
    return list(value) if isinstance(value, (list, tuple)) or hasattr(value, "typecode") else value


def _converted(value: Any, actual: Parameter.Type, declared: Parameter.Type) -> tuple[bool, Any]:
    """``(True, value as the declared type)`` when nothing is lost, ``(True, value)`` when the types agree, else
    ``(False, None)``."""
    if actual == declared:
        return True, value
    if declared == Parameter.Type.DOUBLE and actual == Parameter.Type.INTEGER and abs(value) < _EXACT_INT:
        return True, float(value)
    if declared == Parameter.Type.DOUBLE_ARRAY and actual == Parameter.Type.INTEGER_ARRAY \
            and all(abs(v) < _EXACT_INT for v in value):
        return True, [float(v) for v in value]
    if declared in _ARRAY_TYPES and actual in _ARRAY_TYPES and len(value) == 0:
        return True, []
    return False, None


class TypedParameters:
    """The parameters of one node, each with the type it was declared with (see the module docstring).

    Build it in the node's ``__init__`` after the node's own on-set callback is added (the type check then runs
    first, and the node's callback sees values of the declared type or losslessly convertible to it).

    Parameters
    ----------
    node : rclpy.node.Node
        The node whose parameters these are.
    """

    def __init__(self, node: Node) -> None:
        self.node = node
        self.types: dict[str, Parameter.Type] = {}
        #: each parameter's descriptor as declared (rclpy retypes a dynamically typed descriptor to the type of any
        #: value offered, refused or not: a refusal puts a copy of this one back)
        self.descriptors: dict[str, ParameterDescriptor] = {}
        node.add_pre_set_parameters_callback(self._convert)
        node.add_on_set_parameters_callback(self._check_types)

    def declare(self, name: str, default: Any, description: str = "", *, read_only: bool = False,
                type_: Parameter.Type | None = None, value_range: tuple[float, float] | None = None) -> Any:
        """Declare ``name`` with the type of ``default`` (``type_`` for an empty list) and return its value.

        Parameters
        ----------
        name : str
            The parameter.
        default : bool, int, float, str or list
            Its value when no override gives one.
        description : str
            For ``ros2 param describe``.
        read_only : bool
            Refuse changes after the declaration.
        type_ : rclpy.parameter.Parameter.Type, optional
            The type, when ``default`` does not say it (an empty list).
        value_range : (float, float), optional
            Inclusive bounds of an integer or double parameter (rclpy checks them).

        Returns
        -------
        Any
            The value (override or default), converted to the declared type, arrays as lists.

        Raises
        ------
        ParameterRefused
            The override is refused (a wrong type, or the node's own on-set check): the reason, naming the field.
        """
        declared = type_ if type_ is not None else Parameter.Type.from_parameter_value(default)
        if declared == Parameter.Type.BYTE_ARRAY and isinstance(default, list) and not default:
            raise ValueError(f"{name}: an empty list default needs its type (type_=Parameter.Type.…_ARRAY)")
        descriptor = ParameterDescriptor(description=description, read_only=read_only, dynamic_typing=True)
        if value_range is not None:
            lo, hi = value_range
            if declared == Parameter.Type.INTEGER:
                descriptor.integer_range = [IntegerRange(from_value=int(lo), to_value=int(hi), step=0)]
            else:
                descriptor.floating_point_range = [FloatingPointRange(from_value=float(lo), to_value=float(hi),
                                                                      step=0.0)]
        self.types[name] = declared
        self.descriptors[name] = copy.deepcopy(descriptor)
        try:
            param = self.node.declare_parameter(name, default, descriptor)
        except InvalidParameterValueException as exc:
            # an override an on-set callback refused: its reason alone (it names the field), not rclpy's wrapper
            # "Invalid parameter value (…) for parameter. Reason: <reason>: <name>"
            text = str(exc).split("Reason: ", 1)[-1]
            raise ParameterRefused(text[:-len(name) - 2] if text.endswith(f": {name}") else text) from None
        ok, value = _converted(_as_python(param.value), param.type_, declared)
        if param.type_ != declared and ok and not read_only:
            self.node.set_parameters([Parameter(name, declared, value)])
        return value

    def value(self, name: str) -> Any:
        """The current value of ``name`` (arrays as lists)."""
        return _as_python(self.node.get_parameter(name).value)

    def _convert(self, params: list[Parameter]) -> list[Parameter]:
        """Pre-set: the lossless conversions (new Parameter objects; the others go on unchanged to be refused)."""
        out = []
        for p in params:
            declared = self.types.get(p.name)
            ok, value = (False, None) if declared is None else _converted(_as_python(p.value), p.type_, declared)
            out.append(Parameter(p.name, declared, value) if ok and declared is not None and p.type_ != declared
                       else p)
        return out

    def _check_types(self, params: list[Parameter]) -> SetParametersResult:
        """On-set: every parameter of the declared type (or losslessly convertible: a declaration's override)."""
        for p in params:
            declared = self.types.get(p.name)
            if declared is None:
                continue
            if not _converted(_as_python(p.value), p.type_, declared)[0]:
                shown = "" if p.type_ == Parameter.Type.NOT_SET else f" {_as_python(p.value)!r}"
                # a runtime change: say what stays (a declaration has no old value yet)
                kept = f" (kept: {self.value(p.name)!r})" if self.node.has_parameter(p.name) else ""
                self._retype(params)
                return SetParametersResult(successful=False, reason=f"{p.name}: expected {_TYPE_NAMES[declared]}, "
                                                                    f"got {_TYPE_NAMES[p.type_]}{shown}{kept}")
        return SetParametersResult(successful=True)


    def _retype(self, params: list[Parameter]) -> None:
        """After a refusal: the declared descriptor back on every declared parameter of ``params`` whose offered
        value had another type (rclpy's describe would report that type; the value itself is unchanged)."""
        for p in params:
            declared = self.types.get(p.name)
            if declared is None or p.type_ == declared or not self.node.has_parameter(p.name) \
                    or self.descriptors[p.name].read_only:
                continue
            self.node.set_descriptor(p.name, copy.deepcopy(self.descriptors[p.name]))


def _ros_arg_sections(argv: Sequence[str]) -> list[list[str]]:
    """The ``--ros-args … [--]`` sections of a command line."""
    sections: list[list[str]] = []
    current: list[str] | None = None
    for arg in argv:
        if arg == "--ros-args":
            current = []
            sections.append(current)
        elif arg == "--" and current is not None:
            current = None
        elif current is not None:
            current.append(arg)
    return sections


def override_names(node_name: str, fully_qualified_name: str, argv: Sequence[str]) -> list[str]:
    """The parameter names a command line overrides for this node, in order of appearance (no repeats).

    Parameters
    ----------
    node_name : str
        The node's name (``driver``): a ``-p driver:name:=value`` targets it, ``-p other:name:=value`` does not.
    fully_qualified_name : str
        ``/namespace/name``: a parameter file's section for this node (or ``/**``, every node).
    argv : sequence of str
        The command line (``sys.argv``).

    Returns
    -------
    list of str
    """
    names: list[str] = []
    for section in _ros_arg_sections(argv):
        for flag, arg in zip(section, section[1:]):
            if flag in ("-p", "--param") and ":=" in arg:
                target = arg.split(":=", 1)[0]
                prefix, _, name = target.rpartition(":")
                if prefix and prefix not in (node_name, fully_qualified_name):
                    continue
                names.append(name)
            elif flag == "--params-file":
                try:
                    found = parameter_dict_from_yaml_file(arg, use_wildcard=True,
                                                          target_nodes=[fully_qualified_name])
                except (OSError, RuntimeError):   # rcl itself refuses an unreadable file, before the node exists
                    continue
                names.extend(found)
    return list(dict.fromkeys(names))


def refuse_unknown_parameters(node: Node, argv: Sequence[str] | None = None) -> None:
    """Raise :class:`UnknownParameterError` when the command line overrides a parameter ``node`` does not declare.

    Call it once every parameter is declared, before the node opens a device or a file.

    Parameters
    ----------
    node : rclpy.node.Node
        The node, its parameters declared.
    argv : sequence of str, optional
        The command line its process was started with (default ``sys.argv``).

    Raises
    ------
    UnknownParameterError
        ``unknown parameter 'limits.voltag' (did you mean 'limits.voltage'?)``, one line (several unknown
        parameters: joined by ``; ``).
    """
    unknown = [n for n in override_names(node.get_name(), node.get_fully_qualified_name(),
                                         sys.argv if argv is None else argv) if not node.has_parameter(n)]
    if not unknown:
        return
    declared = list(node.list_parameters([], 0).names)
    parts = []
    for name in unknown:
        close = difflib.get_close_matches(name, declared, n=1)
        parts.append(f"unknown parameter {name!r}" + (f" (did you mean {close[0]!r}?)" if close else ""))
    raise UnknownParameterError("; ".join(parts))
