"""``gonio view DIR|FILE…``: the report, interactive, served on 127.0.0.1 (:mod:`gonio.viewer`): sliders
first, the report below. Same inputs and options as ``gonio report``."""

from __future__ import annotations


def register(sub, common) -> None:
    v = sub.add_parser("view", help="the report, interactive, in the browser (served on 127.0.0.1)",
                       description="Serve the report with sliders for the light direction and the incidence angle "
                                   "on 127.0.0.1 (only to this machine's browser); Ctrl-C stops it. Reads only: "
                                   "nothing is written.")
    common(v)
    v.add_argument("--port", type=int, default=0, help="port (default: a free one)")
    v.add_argument("--no-browser", action="store_true", help="do not open the default browser")
    v.set_defaults(func=run_view)


def _arm_stop_signals() -> None:
    """``gonio view`` says "Ctrl-C to stop", so Ctrl-C (SIGINT) stops it whatever it inherited: the default
    handler, unblocked, even if the parent ignored or blocked SIGINT (a process started from a program
    that does); SIGTERM (a service manager, ``kill``) stops it the same clean way."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        return
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, signal.default_int_handler)


def run_view(args) -> int:
    import webbrowser
    from pathlib import Path

    from gonio.errors import ConfigError
    from gonio.viewer import make_server

    if not 0 <= args.port <= 65535:
        raise ConfigError.field("--port", "port", args.port, "must be in 0..65535")
    try:
        server = make_server(entries(args), port=args.port,
                             title="gonio view: " + ", ".join(Path(s).name or s for s in args.source))
    except OSError as exc:
        raise ConfigError.field("--port", "port", args.port, f"cannot listen ({exc.strerror or exc})") from None
    url = f"http://127.0.0.1:{server.server_address[1]}/"
    _arm_stop_signals()
    print(f"gonio view: serving {url} (Ctrl-C to stop)", flush=True)
    if not args.no_browser:
        webbrowser.open(url)
    try:
        server.serve_forever()
    except KeyboardInterrupt:
        print("gonio view: stopped")
    finally:
        server.server_close()
    return 0


def entries(args):
    """The report's entries from the shared options (sources, --model, --fit, --max-theta)."""
    from gonio.errors import ConfigError
    from gonio.report import load_entries

    if not 0.0 < args.max_theta <= 90.0:
        raise ConfigError.field("--max-theta", "max_theta", args.max_theta, "must be in (0, 90] degrees")
    if args.model and args.fit is not None:
        import sys

        print(f"gonio {args.command}: note: --fit {args.fit} is not fitted: --model gives the models shown "
              "(--fit fits on the spot only without --model)", file=sys.stderr)
    models = [m.strip() for m in (args.fit or "microfacet").split(",") if m.strip()]
    return load_entries(args.source, args.model, fit_models=models, fit_kw={"max_theta_deg": args.max_theta})
