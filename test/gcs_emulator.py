"""A command-level emulator of a PI GCS 2.0 controller for exactly the commands the pi_gcs backend uses (and the
ones pipython itself sends on connect), as the GCS command reference describes them: ``*IDN?``, ``CSV?``, ``ERR?``,
``SVO``, ``SVA``, ``SVA?``, ``WAV … PNT``, ``WSL``, ``WGC``, ``WTR``, ``WGO``, ``WGO?``, ``DRC``, ``RTR``, ``DRR?``.
Unknown commands or bad arguments set GCS error 1 (parameter syntax) or 2 (unknown command), reported by ``ERR?``.
It is a pipython gateway (PIGateway), so the real pipython message layer runs on top of it.  A played wave table
"moves" the axes through a plant callback (volts → position in µm) recorded by the data recorder.
"""
from __future__ import annotations

import numpy as np
from pipython.pidevice.interfaces.pigateway import PIGateway


class GCSEmulator(PIGateway):
    def __init__(self, axes=("1", "2"), plant=None):
        self.axes = list(axes)
        self.plant = plant or (lambda u: 0.1 * u)      # [N, axes] V → [N, axes] µm
        self.log: list[str] = []
        self.err = 0
        self.servo = {a: True for a in self.axes}
        self.sva = {a: 0.0 for a in self.axes}
        self.tables: dict[int, list[float]] = {}
        self.wsl, self.wgc, self.wtr, self.running = {}, {}, {}, {}
        self.drc, self.rtr, self.recorded = {}, 1, {}
        self._out = ""
        self._connected = True

    # -- PIGateway ---------------------------------------------------------------------------------------------
    def __str__(self):
        return "GCSEmulator"

    @property
    def timeout(self):
        return 1000

    def settimeout(self, value):
        pass

    @property
    def connected(self):
        return self._connected

    @property
    def connectionid(self):
        return 0

    def send(self, msg):
        for line in msg.split("\n"):
            if line.strip():
                self.log.append(line.strip())
                self._handle(line.strip())

    def read(self):
        out, self._out = self._out, ""
        return out

    def flush(self):
        self._out = ""

    def close(self):
        self._connected = False

    def unload(self):
        pass

    # -- commands ----------------------------------------------------------------------------------------------
    def _fail(self, code):
        if not self.err:
            self.err = code

    def _pairs(self, args, conv):
        if not args or len(args) % 2:
            self._fail(1)
            return None
        try:
            return [(args[i], conv(args[i + 1])) for i in range(0, len(args), 2)]
        except ValueError:
            self._fail(1)
            return None

    def _handle(self, line):
        cmd, *args = line.split()
        c = cmd.upper()
        if c == "ERR?":
            self._out += f"{self.err}\n"
            self.err = 0
        elif c == "*IDN?":
            self._out += "(c)2026 Physik Instrumente (PI) GmbH & Co. KG, E-727 emulator, 0, 1.0\n"
        elif c == "CSV?":
            self._out += "2.0\n"
        elif c == "SVO":
            for a, v in self._pairs(args, int) or []:
                if a not in self.servo:
                    return self._fail(15)   # illegal axis
                self.servo[a] = bool(v)
        elif c == "SVA":
            for a, v in self._pairs(args, float) or []:
                if a not in self.sva:
                    return self._fail(15)
                if self.servo[a]:
                    return self._fail(5)    # open-loop command while servo on
                self.sva[a] = v
        elif c == "SVA?":
            axes = args or self.axes
            self._out += " \n".join(f"{a}={self.sva[a]:.6f}" for a in axes) + "\n"
        elif c == "WAV":
            # WAV <table> <X|&> PNT <start> <n> <v1> … <vn>
            try:
                t, app, kind, start, n = int(args[0]), args[1], args[2].upper(), int(args[3]), int(args[4])
                vals = [float(v) for v in args[5:]]
            except (IndexError, ValueError):
                return self._fail(1)
            if kind != "PNT" or app not in ("X", "&") or len(vals) != n:
                return self._fail(1)
            if app == "X":
                self.tables[t] = []
            if start != len(self.tables.get(t, [])) + 1:
                return self._fail(1)
            self.tables.setdefault(t, []).extend(vals)
        elif c == "WSL":
            for g, t in self._pairs(args, int) or []:
                self.wsl[int(g)] = t
        elif c == "WGC":
            for g, n in self._pairs(args, int) or []:
                self.wgc[int(g)] = n
        elif c == "WTR":
            if len(args) % 3:
                return self._fail(1)
            for i in range(0, len(args), 3):
                self.wtr[int(args[i])] = (int(args[i + 1]), int(args[i + 2]))
        elif c == "DRC":
            if len(args) % 3:
                return self._fail(1)
            for i in range(0, len(args), 3):
                self.drc[int(args[i])] = (args[i + 1], int(args[i + 2]))
        elif c == "RTR":
            self.rtr = int(args[0])
        elif c == "WGO":
            for g, mode in self._pairs(args, int) or []:
                g = int(g)
                if mode and (g not in self.wsl or self.wsl[g] not in self.tables):
                    return self._fail(1)
                self.running[g] = mode
            self._play()
        elif c == "WGO?":
            gens = [int(g) for g in args] or sorted(self.running)
            self._out += " \n".join(f"{g}=0" for g in gens) + "\n"   # played at once: already finished
        elif c == "DRR?":
            start, n, tabs = int(args[0]), int(args[1]), [int(t) for t in args[2:]]
            cols = [self.recorded.get(t, [])[start - 1:start - 1 + n] for t in tabs]
            header = ["# REM E-727 emulator", "# VERSION = 1", "# TYPE = 1", "# SEPARATOR = 32",
                      f"# DIM = {len(tabs)}", f"# NDATA = {n}", "# END_HEADER"]
            rows = [" ".join(f"{c[i]:.9g}" for c in cols) for i in range(min(len(c) for c in cols))]
            self._out += " \n".join(header + rows) + "\n"
        else:
            self._fail(2)

    def _play(self):
        """Every generator started in open loop plays its table once; the recorder records the axes' positions."""
        gens = [g for g, m in self.running.items() if m]
        if not gens:
            return
        axis_of_gen = {g: self.axes[i] for i, g in enumerate(sorted(self.wsl))}
        u = np.column_stack([self.tables[self.wsl[g]] for g in sorted(gens)])
        for g in gens:
            if self.servo[axis_of_gen[g]]:
                self._fail(5)
                return
        y = self.plant(u)
        for t, (src, opt) in self.drc.items():
            self.recorded[t] = list(y[:, self.axes.index(src)]) if opt == 2 else list(u[:, self.axes.index(src)])
        for g in gens:
            self.running[g] = 0
