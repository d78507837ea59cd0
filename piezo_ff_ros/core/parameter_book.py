"""The compensator's stage parameters as a node holds them, and the transaction of a change (pure).

A change of parameters is validated as a whole — every stage parameter merged and the whole configuration built
(:func:`~.param_map.params_to_config`), ``workspace`` and the tracking front's parameters checked, the front built so
that an unreadable learning file is refused at once — and kept only when the whole set is accepted
(:meth:`ParameterBook.propose`, the node's on-set check); :meth:`~.compensator_core.CompensatorCore.commit` applies it
after.  A refusal is one line starting with the field's name (:class:`Verdict`).  Also the parsing of
``config_yaml`` (several stage parameters as one change) and the comparison of parameter values as the node makes it.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import numpy as np

from .config import ConfigError, PiezoConfig
from .config.loader import safe_yaml
from .param_map import config_to_params, is_config_param, params_to_config
from .status import ERROR
from .tracking.front import FRONT_DEFAULTS, TrackingFront, front_settings, is_front_param

__all__ = ["ParameterBook", "Verdict", "check_box_parameter", "parse_config_yaml", "same_value",
           "CONFIG_YAML_MAX_BYTES"]

#: the largest ``config_yaml`` accepted [bytes] (every stage parameter of the paper's configuration: about 4 kB);
#: checked before parsing, so that a huge string never blocks the node's executor
CONFIG_YAML_MAX_BYTES = 64 * 1024


def same_value(a: Any, b: Any) -> bool:
    """Whether two parameter values are equal (an ``array('d')``, a tuple and a list compare by content).

    Parameters
    ----------
    a, b : Any
        Parameter values (scalars, strings, sequences).

    Returns
    -------
    bool
        Sequences: equal content; scalars: equal and of the same type (``1`` is not ``1.0``).
    """
    if isinstance(a, (list, tuple)) or hasattr(a, "typecode") or isinstance(b, (list, tuple)) or hasattr(b, "typecode"):
        try:
            return list(a) == list(b)
        except TypeError:
            return False
    return bool(a == b) and type(a) is type(b)


def check_box_parameter(flat: Sequence[float], n_axes: int, name: str = "workspace") -> None:
    """Check a box parameter (``workspace``, ``reference_limit``): empty, or ``[min, max]`` per axis, finite,
    ``min < max``.

    Parameters
    ----------
    flat : sequence of float
        ``[min_x, max_x, min_y, max_y, …]`` [m].
    n_axes : int
        Number of axes of the configuration.
    name : str
        The parameter's name (the refusal starts with it).

    Raises
    ------
    ConfigError
        Starting with ``<name>:``, saying what is expected and what was given.
    """
    if flat and (len(flat) != 2 * n_axes or not all(np.isfinite(flat))
                 or any(flat[2 * i] >= flat[2 * i + 1] for i in range(n_axes))):
        raise ConfigError(name, f"expected [min, max] per axis ({2 * n_axes} finite values, min < max), "
                                f"got {list(flat)}")


def parse_config_yaml(text: str) -> dict[str, Any]:
    """Stage parameters from the ``config_yaml`` parameter: a YAML mapping of flat dotted names, nested sections,
    or a params file (``<node>: ros__parameters: …``).

    Parameters
    ----------
    text : str
        The YAML text; empty (or only blanks/comments) is no parameter.

    Returns
    -------
    dict
        ``{dotted stage-parameter name: value}``.

    Raises
    ------
    ConfigError
        One line starting with ``config_yaml:``: larger than :data:`CONFIG_YAML_MAX_BYTES`, nested too deeply or
        an alias bomb (:func:`~.config.loader.safe_yaml`), not YAML, not a mapping, or a name that is not a stage
        parameter.
    """
    d = safe_yaml(text, "config_yaml", max_bytes=CONFIG_YAML_MAX_BYTES) if text.strip() else {}
    if d is None:
        return {}
    if not isinstance(d, dict):
        raise ConfigError("config_yaml", "expected a mapping of stage parameters")
    if len(d) == 1:   # a params file: {node or /**: {ros__parameters: {...}}}
        (only,) = d.values()
        if isinstance(only, dict) and "ros__parameters" in only:
            d = only["ros__parameters"]

    def flatten(prefix: str, m: dict[str, Any], out: dict[str, Any]) -> dict[str, Any]:
        for k, v in m.items():
            key = f"{prefix}{k}"
            if isinstance(v, dict):
                flatten(key + ".", v, out)
            else:
                out[key] = v
        return out

    flat = flatten("", d, {})
    bad = [k for k in flat if not is_config_param(k)]
    if bad:
        raise ConfigError("config_yaml", f"not a stage parameter: {bad[0]}")
    return flat


def _short(d: Mapping[str, Any]) -> str:
    parts = []
    for k, v in d.items():
        s = repr(v)
        parts.append(f"{k}={s if len(s) < 80 else s[:77] + '...'}")
    return ", ".join(parts)


@dataclass(frozen=True)
class Verdict:
    """The answer to a proposed parameter change (the node's on-set callback result).

    Attributes
    ----------
    successful : bool
        Accepted.
    reason : str
        Why not (one line starting with the field's name); empty when accepted.
    log : tuple of (int, str)
        Log lines ``(level, text)``.
    """

    successful: bool
    reason: str = ""
    log: tuple[tuple[int, str], ...] = ()


@dataclass(frozen=True)
class _Candidate:
    updates: dict[str, Any]   # the stage parameters changed
    cfg: PiezoConfig          # the whole configuration they give
    from_yaml: bool           # they came in config_yaml (the stage parameters then read back the new values)


class ParameterBook:
    """The stage parameters as the node holds them, and the transaction of a change: :meth:`propose` (validate,
    keep the candidate) then :meth:`CompensatorCore.commit` (apply it).

    Parameters
    ----------
    base : PiezoConfig
        The base configuration (``config_file``/``variant``): every stage parameter missing from the values comes
        from it.

    Attributes
    ----------
    values : dict
        ``{stage parameter: value}`` as the node's parameters hold them (filled while they are declared).
    front_values : dict
        The tracking front's parameters in use (``preview.*``, ``learning.file``).
    declaring : bool
        True until :meth:`end_declarations`: a change is then only checked (against the base and the parameters
        declared so far), nothing is kept.
    """

    def __init__(self, base: PiezoConfig) -> None:
        self.base = base
        self.values: dict[str, Any] = {}
        self.front_values: dict[str, Any] = dict(FRONT_DEFAULTS)
        self.declaring = True
        self._candidate: _Candidate | None = None
        self._front_candidate: tuple[dict[str, Any], TrackingFront] | None = None
        self._base_params: dict[str, Any] | None = None   # the base's own parameter values (while declaring)

    def end_declarations(self) -> PiezoConfig:
        """Every parameter is declared: the cross-field check of all of them; later changes are transactions.

        Returns
        -------
        PiezoConfig
            The configuration the declared values give.

        Raises
        ------
        ConfigError
            Naming the first field that is wrong.
        """
        self.declaring = False
        self._base_params = None
        return params_to_config(self.values, self.base)

    def propose(self, params: Sequence[tuple[str, Any]],
                build_front: Callable[[Mapping[str, Any]], TrackingFront] | None = None) -> Verdict:
        """Validate a change of parameters (the node's on-set check), all of them together.

        Stage parameters (and those in ``config_yaml``) are merged into :attr:`values` and the whole configuration
        is built (:func:`~.param_map.params_to_config`); ``workspace`` and the tracking front's parameters are
        checked; the front is built here (``build_front``) so that an unreadable learning file is refused now.  An
        accepted change is kept for :meth:`CompensatorCore.commit`.

        Parameters
        ----------
        params : sequence of (str, Any)
            ``(name, value)`` in the order given, arrays as lists; names of other node parameters are passed over.
        build_front : callable, optional
            Builds the tracking front for the merged front parameters (None while declaring: not built).

        Returns
        -------
        Verdict
            Accepted, or refused with a one-line reason starting with the field's name (a stage-parameter refusal
            adds ``(kept: …)`` with the values that stay) and the error to log.
        """
        updates: dict[str, Any] = {}
        from_yaml = False
        front: tuple[dict[str, Any], TrackingFront] | None = None   # kept only if the whole set is accepted
        front_checked = False
        for name, value in params:
            if name == "config_yaml":
                try:
                    from_text = parse_config_yaml(value)
                    for k in from_text:
                        if k not in self.values and not self.declaring:
                            raise ConfigError(k, "unknown parameter")
                except ConfigError as exc:
                    return Verdict(False, str(exc), ((ERROR, f"config_yaml rejected: {exc}"),))
                updates.update(from_text)
                from_yaml = True
            elif name in ("workspace", "reference_limit"):
                try:
                    check_box_parameter(list(value or []), len(self.base.axes), name)
                except ConfigError as exc:
                    return Verdict(False, str(exc))
            elif is_front_param(name) and not front_checked:   # all the front's parameters of the set at once
                front_checked = True
                merged_front = {**self.front_values, **{q: v for q, v in params if is_front_param(q)}}
                try:
                    front_settings(merged_front)
                    if not self.declaring and build_front is not None:   # ≈ 0.3 s: a bad learning file refused now
                        front = (merged_front, build_front(merged_front))
                except ConfigError as exc:
                    return Verdict(False, str(exc))
            elif is_config_param(name):
                updates[name] = value
        if self.declaring and updates:
            # A declared value that is the base's own cannot be wrong on its own, and building the whole stage per
            # parameter (~8 ms each, ~70 of them) was most of the node's start-up; overrides are still built here,
            # naming their field, and end_declarations checks every value together.
            if self._base_params is None:
                self._base_params = config_to_params(self.base)
            base_params = self._base_params
            updates = {k: v for k, v in updates.items() if k not in base_params or not same_value(v, base_params[k])}
        cand = None
        if updates:
            try:
                # while declaring: a partial set, checked against the base for the names declared so far
                cand = params_to_config({**self.values, **updates}, self.base)
            except ConfigError as exc:
                old = {k: self.values.get(k) for k in updates}
                return Verdict(False, f"{exc} (kept: {_short(old)})", ((ERROR, f"parameter change rejected: {exc}"),))
        if not self.declaring:   # the whole set is accepted: what it changes is kept for commit
            self._front_candidate = front
            self._candidate = None if cand is None else _Candidate(updates, cand, from_yaml)
        return Verdict(True)

    def take_candidate(self) -> tuple[dict[str, Any], PiezoConfig, bool] | None:
        """The accepted stage-parameter change, once: ``(updates, configuration, from config_yaml)`` or None.

        Returns
        -------
        tuple or None
            The change kept by :meth:`propose`, forgotten here.
        """
        c, self._candidate = self._candidate, None
        return None if c is None else (c.updates, c.cfg, c.from_yaml)

    def take_front(self) -> tuple[dict[str, Any], TrackingFront] | None:
        """The tracking front built by :meth:`propose`, once: ``(its parameters, the front)`` or None.

        Returns
        -------
        tuple or None
            The front kept by :meth:`propose`, forgotten here.
        """
        f, self._front_candidate = self._front_candidate, None
        return f

    def record_own(self, params: Sequence[tuple[str, Any]]) -> None:
        """The node set parameters itself (a read-back or a revert): its stage parameters hold these values now.

        Parameters
        ----------
        params : sequence of (str, Any)
            ``(name, value)`` as set; names that are not stage parameters are passed over.
        """
        for name, value in params:
            if is_config_param(name):
                self.values[name] = value

    def revert_to(self, cfg: PiezoConfig) -> dict[str, Any]:
        """The stage parameters back to ``cfg``'s values.

        Parameters
        ----------
        cfg : PiezoConfig
            The running configuration.

        Returns
        -------
        dict
            The parameters whose value differed (for the node to set back); empty when none did.
        """
        running = config_to_params(cfg)
        changed = {k: v for k, v in running.items() if not same_value(self.values.get(k), v)}
        if changed:
            self.values.update(running)
        return changed
