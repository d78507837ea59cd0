"""Tracking of known trajectories beyond the paper's model matching.

- :mod:`.linear`: the compensated stage as a linear system (the cascade's ``C(s)`` then ``G_L``), its impulse and
  frequency responses, and a replica of the cascade that predicts the voltage a shaped reference will ask.
- :mod:`.preview`: the preview stage — stable (non-causal) inversion of the compensated dynamics over a preview
  horizon, with a receding-horizon constrained least-squares where the voltage or slew limits bind.
- :mod:`.qp`: the small convex quadratic program solver used by the constrained mode.
- :mod:`.ilc`: iterative learning of a feedforward correction per trajectory, stored and played without a sensor.
- :mod:`.benchmark`: the ``piezo-ff track`` cases (trajectories × methods × truths).
"""
