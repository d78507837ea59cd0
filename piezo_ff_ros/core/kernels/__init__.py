"""Every compiled (numba) kernel of the core chain, in one place.

- :mod:`.limits` — the one voltage limiter (clamp, then slew), used by the driver's guard, the amplifier effect and
  the hysteresis compensators;
- :mod:`.bouc_wen` — the Bouc-Wen increment (one generic source, a two-axis form checked against it), the model
  and the compensator loops;
- :mod:`.modal` — block-diagonal modal banks (every LTI stage) and the creep compensator's loop (generic);
- :mod:`.specialise` — a two-axis bank's loop written out for its structure (straight-line, zero coefficients left
  out, the generic loop's numbers), generated once per structure and cached on disk;
- :mod:`.fused` — whole chains of two-axis stages in one compiled pass per block (same numbers as the stages one by
  one), the kernel generated for the slots present.

Kernels take arrays and named tuples, write their outputs and state in place, and never allocate per sample.
``numba`` compiles them when it is installed (``core/_jit.py``); without it they run as plain Python.
"""
