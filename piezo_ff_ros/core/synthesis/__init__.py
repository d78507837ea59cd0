"""H∞ feedforward synthesis (model matching, paper Eq. 15–23) and controller order reduction."""
