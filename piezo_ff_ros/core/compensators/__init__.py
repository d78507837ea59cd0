"""Streaming compensators: hysteresis (Eq. 6), creep (Eq. 12), vibration (H∞ C(s)), and their cascade."""
