"""A GCS 2.0 controller emulator (a PI E-727-like open-loop piezo controller) served on a loopback TCP port, so that
the pi_gcs backend is exercised through pipython's own ``PISocket`` + ``GCSMessages`` code path with only the device
replaced.

It answers, as the GCS 2.0 command reference describes them, exactly the commands the backend and pipython use:
``*IDN?``, ``CSV?``, ``ERR?``, ``SAI?``, ``TNR?``, ``SPA?`` (data-recorder parameters ``0x16000200``/``0x16000300``),
``VMA?``/``VMI?`` (per piezo channel), ``VOL?``, ``SVO``/``SVO?``, ``SVA``/``SVA?``, ``WMS?``, ``WAV … PNT``, ``WSL``,
``WGC``, ``WTR``, ``WGO``/``WGO?``, ``#9`` (generator running, hex bit mask), ``#7``, ``#24``, ``DRC``, ``RTR``,
``DRR?``.  Bad arguments set GCS error 1, unknown commands 2, an unknown axis 15, an open-loop value while the servo
is on 5, a voltage outside ``[VMI, VMA]`` 302 (nothing applied), a wave table beyond ``WMS?`` 403; ``ERR?`` reports
and clears the first one.

Time is real: a started wave generator runs for ``points · table_rate / servo_rate`` seconds (``#9`` says so),
outputs its table one point per ``table_rate`` servo cycles, then holds the last point (``WGO?`` keeps reporting the
start *mode*, as on the controllers: it is not the running state).  Every value that reaches the output is recorded
with its time in :attr:`GCSEmulator.events` (``(t_monotonic, [volts per axis], source)``): an ``SVA`` at its arrival,
a wave point at its scheduled instant.  Values outside ``[VMI, VMA]`` in a played table are clipped silently, as a
controller's output stage would.

Fault injection: :meth:`GCSEmulator.inject_error` (a command fails with a code), :meth:`GCSEmulator.mute` (a query is
never answered), :meth:`GCSEmulator.drop_after` (the connection is closed after n more commands).

:class:`GCSServer` is the TCP side: one thread, one connection at a time, at most ``max_connections`` in its life,
and it stops itself after ``lifetime`` seconds or on ``close()`` (a context manager).
"""
from __future__ import annotations

import select
import socket
import threading
import time

import numpy as np

IDN = "(c)2026 Physik Instrumente (PI) GmbH & Co. KG, E-727 emulator, 0, 1.0"
DATA_REC_MAX_POINTS, DATA_REC_CHAN_NUMBER = 0x16000200, 0x16000300


class GCSEmulator:
    """The controller's state and command interpreter (see the module docstring).

    Parameters
    ----------
    axes : sequence of str
        Axis identifiers; piezo channel ``i + 1`` drives axis ``i``.
    plant : callable, optional
        ``[N, axes] V → [N, axes] µm``: what the sensor reads while a table plays (record option 2).
    vmin, vmax : float
        The piezo channels' voltage soft limits (``VMI?``/``VMA?``).
    wave_points : int
        Wave table capacity (``WMS?``) per table.
    record_points, record_tables : int
        Data recorder: total points (``0x16000200``) shared by ``record_tables`` tables (``0x16000300``, ``TNR?``).
    servo_rate : float
        Servo cycles per second (time base of ``WTR`` and ``RTR``).
    clock : callable, optional
        The controller's time [s] (default ``time.monotonic``): a test that runs the host on a manual clock gives
        the same one here, so that the recorded set points carry the host's time (the host waits for each answer,
        so its clock stands still while a command is handled).
    """

    def __init__(self, axes=("1", "2"), plant=None, vmin=-200.0, vmax=200.0, wave_points=65536,
                 record_points=262144, record_tables=4, servo_rate=20000.0, output=None, clock=time.monotonic):
        self.clock = clock
        self.axes = list(axes)
        self.plant = plant or (lambda u: 0.1 * u)
        self.vmin, self.vmax = float(vmin), float(vmax)
        self.wave_points, self.record_points, self.record_tables = int(wave_points), int(record_points), int(
            record_tables)
        self.servo_rate = float(servo_rate)
        self.lock = threading.RLock()
        self.log: list[str] = []
        self.events: list[tuple[float, list[float], str]] = []
        self.err = 0
        self.servo = {a: True for a in self.axes}
        out = [0.0] * len(self.axes) if output is None else [float(v) for v in output]
        self.sva = dict(zip(self.axes, out))
        self.output = list(out)
        self.tables: dict[int, list[float]] = {}
        self.wsl, self.wgc, self.wtr, self.wgo_mode = {}, {}, {}, {}
        self.drc, self.rtr, self.recorded = {}, 1, {}
        self._gen_until = 0.0
        self._gen_pending: list[tuple[float, list[float]]] = []
        self._errors: list[list] = []       # [command, code, skip]
        self._muted: set[str] = set()
        self._drop_in: int | None = None
        self.dropped = False

    # -- fault injection ---------------------------------------------------------------------------------------------
    def inject_error(self, command: str, code: int, after: int = 0) -> None:
        """The ``after+1``-th next ``command`` fails with GCS error ``code`` (not applied)."""
        with self.lock:
            self._errors.append([command.upper(), int(code), int(after)])

    def mute(self, command: str) -> None:
        """``command`` (a query) is never answered from now on."""
        with self.lock:
            self._muted.add(command.upper())

    def drop_after(self, n: int) -> None:
        """The connection is closed after ``n`` more commands."""
        with self.lock:
            self._drop_in = int(n)

    # -- the output, as the tests read it -----------------------------------------------------------------------------
    def output_events(self) -> tuple[np.ndarray, np.ndarray]:
        """``(t [s], volts [n, axes])`` of every value that reached the output, in time order (played wave points
        included up to now)."""
        with self.lock:
            self._advance(self.clock())
            ev = sorted(self.events, key=lambda e: e[0])
        return (np.array([e[0] for e in ev]), np.array([e[1] for e in ev], dtype=float).reshape(len(ev), -1))

    def generator_running(self) -> bool:
        with self.lock:
            return self.clock() < self._gen_until

    # -- commands ----------------------------------------------------------------------------------------------------
    def handle(self, line: str) -> tuple[str | None, bool]:
        """Execute one command; ``(reply or None, drop the connection)``."""
        now = self.clock()
        with self.lock:
            self._advance(now)
            self.log.append(line)
            cmd = line.split()[0].upper() if line.strip() else line
            reply = None
            if cmd in self._muted:
                reply = None
            else:
                for e in self._errors:
                    if e[0] == cmd:
                        if e[2] > 0:
                            e[2] -= 1
                            break
                        self._errors.remove(e)
                        self._fail(e[1])
                        return self._reply_for_failed(cmd), self._tick_drop()
                reply = self._handle(line, now)
            return reply, self._tick_drop()

    def _tick_drop(self) -> bool:
        if self._drop_in is None:
            return False
        self._drop_in -= 1
        if self._drop_in < 0:
            self.dropped = True
            return True
        return False

    def _reply_for_failed(self, cmd):
        return "0\n" if cmd.endswith("?") or cmd.startswith("#") or len(cmd) == 1 else None

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

    @staticmethod
    def _lines(items):
        return " \n".join(items) + "\n"

    def _channels(self, args):
        try:
            chans = [int(c) for c in args] or list(range(1, len(self.axes) + 1))
        except ValueError:
            self._fail(1)
            return None
        if any(not 1 <= c <= len(self.axes) for c in chans):
            self._fail(1)
            return None
        return chans

    def _set_output(self, values, t, source):
        self.output = list(values)
        self.events.append((t, list(values), source))

    def _handle(self, line, now):
        if len(line) == 1 and ord(line) < 32:          # single-character commands
            code = ord(line)
            if code == 9:
                bits = 0
                if now < self._gen_until:
                    for g, m in self.wgo_mode.items():
                        if m:
                            bits |= 1 << (g - 1)
                return f"{bits:X}\n"
            if code == 7:
                return chr(177) + "\n"
            if code == 24:
                self._stop_generators(now)
                self._fail(10)
                return None
            self._fail(2)
            return None
        cmd, *args = line.split()
        c = cmd.upper()
        if c == "ERR?":
            out, self.err = f"{self.err}\n", 0
            return out
        if c == "*IDN?":
            return IDN + "\n"
        if c == "CSV?":
            return "2.0\n"
        if c == "SAI?":
            return self._lines(self.axes)
        if c == "TNR?":
            return f"{self.record_tables}\n"
        if c == "SPA?":
            try:
                item, param = args[0], int(args[1], 0)
            except (IndexError, ValueError):
                self._fail(1)
                return "\n"
            values = {DATA_REC_MAX_POINTS: self.record_points, DATA_REC_CHAN_NUMBER: self.record_tables}
            if param not in values:
                self._fail(54)
                return "\n"
            return f"{item} {args[1]}={values[param]}\n"
        if c in ("VMA?", "VMI?"):
            chans = self._channels(args)
            if chans is None:
                return "\n"
            v = self.vmax if c == "VMA?" else self.vmin
            return self._lines([f"{ch}={v:.4f}" for ch in chans])
        if c == "VOL?":
            chans = self._channels(args)
            if chans is None:
                return "\n"
            return self._lines([f"{ch}={self.output[ch - 1]:.6f}" for ch in chans])
        if c == "SVO":
            for a, v in self._pairs(args, int) or []:
                if a not in self.servo:
                    self._fail(15)
                    return None
                self.servo[a] = bool(v)
            return None
        if c == "SVO?":
            return self._lines([f"{a}={int(self.servo[a])}" for a in (args or self.axes)])
        if c == "SVA":
            pairs = self._pairs(args, float) or []
            for a, v in pairs:
                if a not in self.sva:
                    self._fail(15)
                    return None
                if self.servo[a]:
                    self._fail(5)
                    return None
                if now < self._gen_until:
                    self._fail(73)
                    return None
                if not self.vmin <= v <= self.vmax:
                    self._fail(302)
                    return None
            if pairs:
                for a, v in pairs:
                    self.sva[a] = v
                self._set_output([self.sva[a] for a in self.axes], now, "SVA")
            return None
        if c == "SVA?":
            axes = args or self.axes
            if any(a not in self.sva for a in axes):
                self._fail(15)
                return "\n"
            return self._lines([f"{a}={self.sva[a]:.6f}" for a in axes])
        if c == "WMS?":
            tabs = args or [str(t) for t in range(1, len(self.axes) + 1)]
            return self._lines([f"{t}={self.wave_points}" for t in tabs])
        if c == "WAV":
            # WAV <table> <X|&> PNT <start> <n> <v1> … <vn>
            try:
                t, app, kind, start, n = int(args[0]), args[1], args[2].upper(), int(args[3]), int(args[4])
                vals = [float(v) for v in args[5:]]
            except (IndexError, ValueError):
                self._fail(1)
                return None
            if kind != "PNT" or app not in ("X", "&") or len(vals) != n:
                self._fail(1)
                return None
            if app == "X":
                self.tables[t] = []
            if start != len(self.tables.get(t, [])) + 1:
                self._fail(1)
                return None
            if len(self.tables.get(t, [])) + n > self.wave_points:
                self._fail(403)
                return None
            self.tables.setdefault(t, []).extend(vals)
            return None
        if c == "WSL":
            for g, t in self._pairs(args, int) or []:
                self.wsl[int(g)] = t
            return None
        if c == "WGC":
            for g, n in self._pairs(args, int) or []:
                self.wgc[int(g)] = n
            return None
        if c == "WTR":
            if not args or len(args) % 3:
                self._fail(1)
                return None
            for i in range(0, len(args), 3):
                self.wtr[int(args[i])] = (int(args[i + 1]), int(args[i + 2]))
            return None
        if c == "DRC":
            if not args or len(args) % 3:
                self._fail(1)
                return None
            for i in range(0, len(args), 3):
                self.drc[int(args[i])] = (args[i + 1], int(args[i + 2]))
            return None
        if c == "RTR":
            try:
                self.rtr = int(args[0])
            except (IndexError, ValueError):
                self._fail(1)
            return None
        if c == "WGO":
            pairs = self._pairs(args, int) or []
            for g, mode in pairs:
                g = int(g)
                if mode and (g not in self.wsl or self.wsl[g] not in self.tables):
                    self._fail(75)
                    return None
            if any(m for _, m in pairs) and now < self._gen_until:
                self._fail(73)
                return None
            for g, mode in pairs:
                self.wgo_mode[int(g)] = mode
            if any(m for _, m in pairs):
                self._play(now)
            else:
                self._stop_generators(now)
            return None
        if c == "WGO?":
            gens = [int(g) for g in args] or sorted(self.wgo_mode)
            return self._lines([f"{g}={self.wgo_mode.get(g, 0)}" for g in gens])
        if c == "DRR?":
            try:
                start, n, tabs = int(args[0]), int(args[1]), [int(t) for t in args[2:]]
            except (IndexError, ValueError):
                self._fail(1)
                return "\n"
            cols = [self.recorded.get(t, [])[start - 1:start - 1 + n] for t in tabs]
            if not cols or min(len(c) for c in cols) < n:
                self._fail(77)
                return "\n"
            header = ["# REM E-727 emulator", "# VERSION = 1", "# TYPE = 1", "# SEPARATOR = 32",
                      f"# DIM = {len(tabs)}", f"# NDATA = {n}", "# END_HEADER"]
            rows = [" ".join(f"{c[i]:.9g}" for c in cols) for i in range(n)]
            return self._lines(header + rows)
        self._fail(2)
        return None

    def _play(self, now):
        """The started generators play their tables once (WGC 1) at WTR's rate; the recorder records at RTR."""
        gens = sorted(g for g, m in self.wgo_mode.items() if m)
        axis_of_gen = {g: self.axes[g - 1] for g in gens}
        for g in gens:
            if self.servo[axis_of_gen[g]]:
                self._fail(5)
                self.wgo_mode[g] = 0
                return
        lengths = {len(self.tables[self.wsl[g]]) for g in gens}
        if len(lengths) != 1:
            self._fail(1)
            return
        n = lengths.pop()
        rate = self.wtr.get(gens[0], (1, 0))[0]
        dt = rate / self.servo_rate
        u = np.tile(np.array(self.output, dtype=float), (n, 1))
        for g in gens:
            u[:, self.axes.index(axis_of_gen[g])] = self.tables[self.wsl[g]]
        u = np.clip(u, self.vmin, self.vmax)          # the output stage clips, silently
        self._gen_pending = [(now + i * dt, list(row)) for i, row in enumerate(u)]
        self._gen_until = now + n * dt
        y = self.plant(u)
        for t, (src, opt) in self.drc.items():
            col = self.axes.index(src) if src in self.axes else 0
            self.recorded[t] = list(y[:, col]) if opt == 2 else list(u[:, col])

    def _advance(self, now):
        """Move the played wave points whose instant has come to the output."""
        while self._gen_pending and self._gen_pending[0][0] <= now:
            t, row = self._gen_pending.pop(0)
            self._set_output(row, t, "WAV")

    def _stop_generators(self, now):
        self._gen_pending = [p for p in self._gen_pending if p[0] <= now]
        self._advance(now)
        self._gen_until = min(self._gen_until, now)
        for g in self.wgo_mode:
            self.wgo_mode[g] = 0


class GCSServer:
    """Serve a :class:`GCSEmulator` on ``127.0.0.1:<port>`` (see the module docstring)."""

    def __init__(self, emulator: GCSEmulator | None = None, lifetime: float = 60.0, max_connections: int = 8):
        self.emu = emulator or GCSEmulator()
        self.lifetime = float(lifetime)
        self.max_connections = int(max_connections)
        self._sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self._sock.bind(("127.0.0.1", 0))
        self._sock.listen(1)
        self.port = self._sock.getsockname()[1]
        self.connections = 0
        self.open_connections = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._serve, name="gcs-emulator", daemon=True)
        self._thread.start()

    def __enter__(self) -> "GCSServer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5)
        self._sock.close()

    def _serve(self) -> None:
        deadline = time.monotonic() + self.lifetime
        while not self._stop.is_set() and time.monotonic() < deadline and self.connections < self.max_connections:
            r, _, _ = select.select([self._sock], [], [], 0.05)
            if not r:
                continue
            conn, _ = self._sock.accept()
            self.connections += 1
            self.open_connections += 1
            try:
                self._serve_one(conn, deadline)
            finally:
                self.open_connections -= 1
                conn.close()

    def _serve_one(self, conn: socket.socket, deadline: float) -> None:
        def drop() -> None:
            conn.shutdown(socket.SHUT_RDWR)
        serve_stream(self.emu, conn.fileno(), conn.recv, conn.sendall, drop, deadline, self._stop)


def serve_stream(emu: GCSEmulator, fd: int, recv, send, drop, deadline: float, stop: threading.Event) -> None:
    """Answer the GCS commands arriving on ``fd`` (``recv``/``send``) until EOF, ``stop`` or ``deadline``."""
    buf = ""
    while not stop.is_set() and time.monotonic() < deadline:
        r, _, _ = select.select([fd], [], [], 0.05)
        if not r:
            continue
        try:
            data = recv(65536)
        except OSError:
            return
        if not data:
            return                                   # the client closed the connection
        buf += data.decode("cp1252")
        while buf:
            if ord(buf[0]) < 32 and buf[0] not in "\n\r":
                line, buf = buf[0], buf[1:]
            else:
                cut = buf.find("\n")
                if cut < 0:
                    break
                line, buf = buf[:cut].strip(), buf[cut + 1:]
                if not line:
                    continue
            reply, dropped = emu.handle(line)
            if reply:
                send(reply.encode("cp1252"))
            if dropped:
                drop()
                return


class GCSSerialServer:
    """Serve a :class:`GCSEmulator` on a pseudo-terminal: :attr:`port` is a serial port path that pyserial (and so
    pipython's ``PISerial``) opens like a controller's RS-232 or USB serial port."""

    def __init__(self, emulator: GCSEmulator | None = None, lifetime: float = 60.0):
        import os
        import tty

        self.emu = emulator or GCSEmulator()
        self._master, slave = os.openpty()
        tty.setraw(slave)
        self.port = os.ttyname(slave)
        self._slave = slave
        self._stop = threading.Event()

        def send(b):
            os.write(self._master, b)

        self._thread = threading.Thread(
            target=serve_stream, name="gcs-emulator-serial", daemon=True,
            args=(self.emu, self._master, lambda n: os.read(self._master, n), send, self._stop.set,
                  time.monotonic() + lifetime, self._stop))
        self._thread.start()

    def __enter__(self) -> "GCSSerialServer":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        import os

        self._stop.set()
        self._thread.join(timeout=5)
        for fd in (self._master, self._slave):
            try:
                os.close(fd)
            except OSError:
                pass
