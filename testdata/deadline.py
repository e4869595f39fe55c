"""Calls that must not hang: run one on a thread and give up on it after a deadline (tests of
FIFOs and devices, the robustness benchmark's fuzzers)."""

from __future__ import annotations

import threading


def run_with_deadline(fn, seconds: float):
    """(finished, value, exception) of fn() run on a daemon thread for at most `seconds`; a
    call still running then is left behind (finished False)."""
    box = {}

    def run():
        try:
            box["value"] = fn()
        except BaseException as exc:      # noqa: BLE001 - handed back to the caller
            box["error"] = exc
    t = threading.Thread(target=run, daemon=True)
    t.start()
    t.join(seconds)
    return not t.is_alive(), box.get("value"), box.get("error")


def finishes(fn, seconds: float = 20.0):
    """fn()'s result, its exception re-raised, or AssertionError if it is still blocked after
    `seconds`."""
    done, value, error = run_with_deadline(fn, seconds)
    if not done:
        raise AssertionError(f"still blocked after {seconds} s")
    if error is not None:
        raise error
    return value
