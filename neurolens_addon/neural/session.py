"""onnxruntime for the learned lens: execution providers, sessions checked against the graph
signatures of neural.modelfile.GRAPH_IO, and the sha256 check of a graph file.

onnxruntime is imported only inside these functions, so the add-on (and neural.model) imports
without it: a learned lens then fails to load with a message, and nothing else is affected.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

from ..core.errors import ModelError
from .modelfile import GRAPH_IO


def choose_providers(requested=None) -> list[str]:
    """The execution providers to use: `requested`, else CUDA when onnxruntime offers it, then
    CPU."""
    import onnxruntime as ort
    if requested is not None:
        return list(requested)
    avail = ort.get_available_providers()
    return (["CUDAExecutionProvider"] if "CUDAExecutionProvider" in avail else []) + \
        ["CPUExecutionProvider"]


def verify_file(path: Path, sha256: str) -> bytes:
    """The graph file's bytes (a regular file within MAX_GRAPH_BYTES: core.safe_io); ModelError
    unless its sha256 is the one model.json records."""
    from ..core.safe_io import UnreadableFile, read_regular
    from .modelfile import MAX_GRAPH_BYTES
    try:
        data = read_regular(path, MAX_GRAPH_BYTES, "ONNX graph")
    except UnreadableFile as e:
        raise ModelError(e.reason, path=str(path)) from None
    have = hashlib.sha256(data).hexdigest()
    if have != sha256.lower():
        raise ModelError(f"sha256 {have[:16]}... does not match model.json's {sha256[:16]}...: "
                         "the file is truncated, corrupted or belongs to another model",
                         path=str(path))
    return data


def no_telemetry(ort) -> None:
    """onnxruntime records telemetry events (device id, process path, session events) unless
    told not to: every session the add-on or the trainer makes is opened after this."""
    off = getattr(ort, "disable_telemetry_events", None)
    if off is not None:
        off()


def open_session(path: Path, providers, threads, data: bytes):
    """An onnxruntime session of the graph `data` (verify_file's bytes of the file at `path`,
    named as in GRAPH_IO), refused with ModelError when onnxruntime cannot load it or its
    inputs and outputs are not GRAPH_IO's. Telemetry is off."""
    import onnxruntime as ort
    no_telemetry(ort)
    so = ort.SessionOptions()
    if threads is not None:
        so.intra_op_num_threads = int(threads)
    so.inter_op_num_threads = 1
    # no busy-waiting between runs: a renderer interleaves lens batches with its own work
    # (scene ray casts), which spinning onnxruntime threads would slow down
    so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    so.log_severity_level = 3
    try:
        sess = ort.InferenceSession(data, so, providers=providers)
    except Exception as e:  # onnxruntime raises its own exception types
        raise ModelError(f"onnxruntime cannot load the graph: {str(e).strip()[:300]}",
                         path=str(path)) from None
    want_in, want_out = GRAPH_IO[path.name]
    ins, outs = sess.get_inputs(), sess.get_outputs()
    got_in, got_out = [i.name for i in ins], [o.name for o in outs]
    if got_in != [w[0] for w in want_in] or got_out != [w[0] for w in want_out]:
        raise ModelError(f"graph inputs {got_in} / outputs {got_out}, expected "
                         f"{[w[0] for w in want_in]} / {[w[0] for w in want_out]}", path=str(path))
    problems = []
    for kind, have, want in (("input", ins, want_in), ("output", outs, want_out)):
        for a, (name, typ, shape) in zip(have, want):
            ok = a.type == f"tensor({typ})" and len(a.shape) == len(shape) and all(
                isinstance(s, str) or s == h for s, h in zip(shape, a.shape))
            if not ok:
                problems.append(f"{kind} {name} is {a.type} {a.shape}, expected "
                                f"{typ} [{', '.join(map(str, shape))}]")
    if problems:
        raise ModelError("; ".join(problems), path=str(path))
    return sess
