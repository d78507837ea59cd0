"""Models of the positioner: Bouc-Wen hysteresis, creep, dynamics, the plant chain and unmodelled effects."""
