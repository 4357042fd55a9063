"""Live output of ``runtime-track``: streaming every frame over UDP (``--vmc``, ``--osc``) and
optional One-Euro smoothing (``--smooth``) of what is streamed and of ``motion.bvh``.

:class:`LiveOutput` wraps the :class:`~runtime.export.results.ResultWriter` with the same
``write_frame`` call, so the tracking loop does not change. Per frame it

1. keeps the raw pose for ``poses.jsonl`` (always: it is the record of what was tracked);
2. with smoothing, filters the pose q (:class:`~runtime.export.one_euro.PoseSmoother`) for the
   BVH and VMC, and the named joints for OSC; a frame without a pose restarts the filter;
3. writes the files, then sends one bundle per target (:mod:`runtime.export.vmc`,
   :mod:`runtime.export.osc`).

Sending never blocks or stops tracking: the socket is non-blocking, the host name is resolved
once at start-up (a bad host is a bad option, exit 2), and a failed send (no route, a full
socket buffer, ...) is counted, warned about once on stderr, and reported in ``summary.json``
under ``extra``: ``stream`` (targets and smoothing), ``stream_sent`` and ``stream_errors``
(per target) and ``stream_last_error``. UDP has no connection: a port nobody listens on is no
error, the datagrams are simply lost.

``python-osc`` is needed only when a target is given (``pip install 'depthmocap[stream]'``).
"""

from __future__ import annotations

import argparse
import dataclasses
import socket
import sys

import numpy as np
from depthmocap.shared.body import BodyShape
from depthmocap.shared.config import config_to_dict

from .one_euro import PoseSmoother, SmoothingConfig
from .writer_stage import WriterStage

__all__ = [
    "LiveOutputError",
    "UdpTarget",
    "LiveOutput",
    "add_live_args",
    "live_output_from_args",
    "parse_target",
]


class LiveOutputError(ValueError):
    """A bad live-output option (unparsable or unresolvable target, missing python-osc)."""


def parse_target(text: str, option: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[v6addr]:PORT`` for IPv6) -> (host, port)."""
    host, sep, port_text = text.rpartition(":")
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    try:
        port = int(port_text)
    except ValueError:
        port = -1
    if not sep or not host or not 0 < port < 65536:
        raise LiveOutputError(f"{option} wants HOST:PORT (e.g. 127.0.0.1:39539), got {text!r}")
    return host, port


class UdpTarget:
    """A python-osc UDP client to one resolved address that never blocks, counting failures.

    Args:
        name: what it sends (``"vmc"``, ``"osc"``): the key in the summary.
        host, port: where to (a host name is resolved here, once).
    Raises:
        LiveOutputError: python-osc is missing or the host cannot be resolved.
    """

    def __init__(self, name: str, host: str, port: int) -> None:
        try:
            from pythonosc.udp_client import UDPClient
        except ImportError:
            raise LiveOutputError(
                f"--{name} needs the python-osc package: pip install 'depthmocap[stream]'"
            ) from None
        try:
            info = socket.getaddrinfo(host, port, type=socket.SOCK_DGRAM)[0]
        except (OSError, UnicodeError) as err:
            raise LiveOutputError(f"--{name}: cannot resolve host {host!r} ({err})") from None
        family, address = info[0], info[4][0]
        self.name = name
        self.target = f"[{host}]:{port}" if ":" in host else f"{host}:{port}"
        # A numeric address: sendto() then never waits on a name look-up. The client's
        # socket is non-blocking (python-osc sets it so): a full buffer is an error, not a wait.
        self.client = UDPClient(address, port, family=family)
        self.sent = 0
        self.errors = 0
        self.last_error: str | None = None

    def send(self, build) -> None:
        """Send the bundle ``build()`` makes; any failure is counted, never raised."""
        try:
            self.client.send(build())
        except Exception as err:  # noqa: BLE001 - tracking must go on whatever sending does
            self.errors += 1
            self.last_error = f"{type(err).__name__}: {err}"
            if self.errors == 1:
                print(
                    f"warning: --{self.name} {self.target}: sending failed ({self.last_error}); "
                    "tracking goes on, failures are counted in summary.json",
                    file=sys.stderr,
                )
        else:
            self.sent += 1

    def close(self) -> None:
        try:
            self.client.close()
        except OSError:
            pass


class LiveOutput(WriterStage):
    """The result writer plus streaming and smoothing (module docstring).

    Args:
        body: the body in use (VMC bone offsets and rotations).
        fps: the stream's nominal rate (the filter's step when timestamps do not advance).
        vmc, osc: the targets, or None.
        smoothing: One-Euro parameters, or None for no smoothing.
    Call :meth:`wrap` with the result writer before the first frame.
    """

    def __init__(
        self,
        body: BodyShape,
        fps: float,
        *,
        vmc: UdpTarget | None = None,
        osc: UdpTarget | None = None,
        smoothing: SmoothingConfig | None = None,
    ) -> None:
        self.body = body
        self.vmc, self.osc = vmc, osc
        self.smoothing = smoothing
        self.smoother = PoseSmoother(smoothing, fps) if smoothing is not None else None
        self.writer = None

    @property
    def targets(self) -> list[UdpTarget]:
        return [t for t in (self.vmc, self.osc) if t is not None]

    def wrap(self, writer) -> LiveOutput:
        """Use ``writer`` (a ResultWriter) for the files; returns self, to use in its place."""
        self.writer = writer
        writer.extra["stream"] = {
            "vmc": self.vmc.target if self.vmc else None,
            "osc": self.osc.target if self.osc else None,
            "smoothing": config_to_dict(self.smoothing) if self.smoothing else None,
        }
        self._report()
        return self

    def update_body(self, body: BodyShape) -> None:
        """As :meth:`ResultWriter.update_body`; the VMC bones follow the new body too."""
        self.body = body
        self.writer.update_body(body)

    def _report(self) -> None:
        extra = self.writer.extra
        extra["stream_sent"] = {t.name: t.sent for t in self.targets}
        extra["stream_errors"] = {t.name: t.errors for t in self.targets}
        last = {t.name: t.last_error for t in self.targets if t.last_error}
        if last:
            extra["stream_last_error"] = last

    def write_frame(
        self,
        index: int,
        time: float,
        status: str,
        joints: np.ndarray | None,
        q: np.ndarray | None,
        errors: dict[str, float],
        observed: np.ndarray | None = None,
    ) -> None:
        """As :meth:`ResultWriter.write_frame`; then the frame is streamed."""
        has_pose = status != "lost" and q is not None and bool(np.isfinite(q).all())
        out_q = np.asarray(q, dtype=np.float64) if has_pose else None
        out_joints = joints
        if self.smoother is not None:
            if has_pose:
                out_q = self.smoother.pose(time, out_q)
                if joints is not None and self.osc is not None:
                    out_joints = self.smoother.joints(time, joints)
            else:
                self.smoother.reset()
        self.writer.write_frame(
            index, time, status, joints, q, errors, observed=observed,
            bvh_q=out_q if self.smoother is not None else ...,
        )  # fmt: skip
        if self.vmc is not None:
            from .vmc import vmc_bundle

            self.vmc.send(lambda: vmc_bundle(time, out_q, self.body))
        if self.osc is not None:
            from .osc import osc_bundle

            self.osc.send(lambda: osc_bundle(index, time, status, out_joints, observed))
        self._report()

    def close(self) -> dict:
        """Close the sockets, then the result writer; returns its final summary."""
        for t in self.targets:
            t.close()
        self._report()
        return self.writer.close()


# --------------------------------------------------------------------------------------------
# Options of runtime-track

_SMOOTH_FIELDS = {f.name: f for f in dataclasses.fields(SmoothingConfig)}


def add_live_args(parser: argparse.ArgumentParser) -> None:
    """The ``live output`` option group of ``runtime-track``."""
    g = parser.add_argument_group(
        "live output (needs python-osc: pip install 'depthmocap[stream]')"
    )
    g.add_argument(
        "--vmc",
        metavar="HOST:PORT",
        help="send the skeleton every frame as VMC protocol bones (OSC/UDP; VSeeFace, EVMC4U, "
        "the Blender VMC add-on; their usual port is 39539)",
    )
    g.add_argument(
        "--osc",
        metavar="HOST:PORT",
        help="send every frame as plain OSC: /depthmocap/frame and /depthmocap/joint/<name>",
    )
    g.add_argument(
        "--smooth",
        action="store_true",
        help="One-Euro filter the streamed skeleton and motion.bvh (poses.jsonl stays raw)",
    )
    for name, f in _SMOOTH_FIELDS.items():
        g.add_argument(
            "--smooth-" + name.replace("_", "-"),
            dest="smooth_" + name,
            type=float,
            metavar="X",
            help=f"{f.metadata['help']} (default: {f.default}; with --smooth)",
        )


def live_output_from_args(
    args: argparse.Namespace, body: BodyShape, fps: float
) -> LiveOutput | None:
    """The live output the options ask for, or None when they ask for none.

    Raises:
        LiveOutputError: a bad target, python-osc missing, or bad smoothing values.
    """
    given = {n: getattr(args, "smooth_" + n, None) for n in _SMOOTH_FIELDS}
    given = {n: v for n, v in given.items() if v is not None}
    smooth = getattr(args, "smooth", False)
    if given and not smooth:
        flags = ", ".join("--smooth-" + n.replace("_", "-") for n in given)
        raise LiveOutputError(f"{flags} needs --smooth")
    smoothing = None
    if smooth:
        smoothing = SmoothingConfig(**given)
        try:
            smoothing.validate()
        except ValueError as err:
            raise LiveOutputError(str(err)) from None
    vmc_arg, osc_arg = getattr(args, "vmc", None), getattr(args, "osc", None)
    if smoothing is None and vmc_arg is None and osc_arg is None:
        return None
    vmc = UdpTarget("vmc", *parse_target(vmc_arg, "--vmc")) if vmc_arg is not None else None
    osc = UdpTarget("osc", *parse_target(osc_arg, "--osc")) if osc_arg is not None else None
    return LiveOutput(body, fps, vmc=vmc, osc=osc, smoothing=smoothing)
