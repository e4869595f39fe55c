"""OSL for the learned lens: a trained NeuroLens model evaluated in the shader, float32.

Semantics of neural.reference / neural.model. A camera ray (sensor point, pupil-aware direction
d = (u, v, w) from the slab pupil, cycles.follow) flies freely to the input plane Pi_1:
x_1 = x_s + (z_1 - z_s) u / w. Each stage (rear group: Pi_1 -> stop plane; front group:
stop plane -> Pi_2) then
  1. goes to the radial frame, X = (r, u_r, u_t, w[, lambda]) with r = |(x, y)|,
     (c, s) = (x, y) / r ((1, 0) at r = 0), u_r = c u + s v, u_t = c v - s u;
  2. drops the ray outside the learned domain: lo <= X <= hi, and the occupancy cell of
     (r, u_r, u_t), f = (X - lo_o) shape / (hi_o - lo_o), 0 <= f <= shape,
     cell = min(floor(f), shape - 1) (C order), must be set; with dispersion lambda must lie in
     the trained range;
  3. descends the kd-tree (left when X[axis] < split) to a leaf cell k;
  4. evaluates the cell's ensemble on x = (X - mean_x) / scale_x. Averaging M members
     Y_m = scale_y (W3 tanh(W2 tanh(W1 x + b1) + b2) + b3 + L phi_p(x)) + mean_y
     is linear in the last layer, so the shader uses the pre-averaged
         Y = mean_y + scale_y mean_m(b3) + (scale_y mean_m L) phi(x)
             + sum_m (scale_y / M) W3_m tanh(W2_m tanh(W1_m x + b1_m) + b2_m),
     phi the monomials the members use (neural.modelfile.member_terms: their skip_terms, else
     every monomial of degree 1..p; a member without one gets a zero coefficient), each
     built from its prefix, m_t = m_prefix x_last; a cell whose x_norm names a reference
     wavelength l0 sees lambda as mu = (l0 / lambda)^2, one that names a w residual column
     sees w as -q^3 (w + 3) / (8 (1 + w)^3), q = u_r^2 + u_t^2
     (neural.reference.cell_features). A
     skip with zero coefficients (the sparse basis: mirror-symmetric parity split) keeps its
     monomials so that each output's nonzero terms are one contiguous range of them (the
     even outputs' and the odd ones') and evaluates each output over its range only;
  5. rotates (x'_r, x'_t, u'_r, u'_t) back by (c, s), w' = sqrt(1 - u'^2 - v'^2) (dropped when
     negative), z' = the stage's output plane. A "propagate" stage is exact free flight.
Between the stages the stop shape is tested exactly at the stop plane (stop_shape). Weights are
packed per stage into constant arrays with per-cell offsets; the kd-tree and the occupancy grid
(30 bits per int) are constant arrays too. Only radial-frame models have a shader: a model in
the cartesian frame (an anamorphic lens, core.irf) renders in the NeuroLens engine, and Cycles
renders that lens exactly (CameraSpec.from_setup).
"""

from __future__ import annotations

import base64
import dataclasses
from dataclasses import dataclass

import numpy as np

from ..core.errors import ModelError
from ..core.paraxial import paraxial_data
from ..neural.modelfile import member_terms
from ..neural.reference import prefix_closure
from .frame import assemble
from ..core.oslfmt import comment_text, float_array, flt, indent, int_array
from .follow import lens_state
from .ghosts import with_ghosts
from ..core.aperture import shader_shape
from .stop_shape import inside_osl

OCC_BITS_PER_INT = 30


@dataclass(frozen=True)
class ModelTables:
    """A checked model.json: its directory name and metadata (weights, trees, domain)."""

    name: str
    meta: dict


def load_model(spec) -> ModelTables:
    """Read and check the spec's model.json (neural.modelfile's checks and messages), refusing a
    model trained for another lens. The shader needs no ONNX graph, so onnxruntime is not
    needed here."""
    from ..core.irf import RADIAL, model_frames
    from ..neural.modelfile import read_model_json
    table = getattr(spec.lens, "table", False)    # the model is the lens: nothing to match
    directory, meta, _, _ = read_model_json(spec.model_dir, None if table else spec.lens)
    other = [f.name for f in model_frames(meta) if f is not RADIAL]
    if other:
        raise ModelError(f"the Cycles learned camera evaluates radial-frame models only, not "
                         f"{other[0]!r} stages: render this lens with the exact camera or the "
                         "NeuroLens engine", path=str(directory / "model.json"), field="frame")
    return ModelTables(directory.name, meta)


def _occupancy_words(occ: dict) -> tuple[np.ndarray, list[int]]:
    shape = [int(s) for s in occ["shape"]]
    n = int(np.prod(shape))
    bits = np.unpackbits(np.frombuffer(base64.b64decode(occ["bits"]), dtype=np.uint8))[:n]
    pad = (-n) % OCC_BITS_PER_INT
    groups = np.concatenate([bits, np.zeros(pad, np.uint8)]).reshape(-1, OCC_BITS_PER_INT)
    words = (groups.astype(np.int64) << np.arange(OCC_BITS_PER_INT)).sum(axis=1)
    return words, shape


def _stage_terms(stage: dict, d_in: int) -> list[tuple[int, ...]]:
    """Every skip monomial the stage's members use (their skip_terms, else every monomial up
    to their skip_degree) with every prefix a product needs, in prefix-closure order: the
    shader builds each from one before it (m_t = m_prefix x_last). A full-basis stage's are
    monomial_terms(d_in, degree), in its order."""
    union = set()
    for cell in stage["cells"]:
        for m in cell["members"]:
            union.update(member_terms(m, d_in))
    return prefix_closure(union)


def _pack_stage(stage: dict, d_in: int):
    """Per-cell constants: (x mean, 1 / x scale, wavelength reference, bias, the averaged
    skip (4 x T, or its nonzero terms per output), packed MLPs, offsets, H, T)."""
    cells = stage["cells"]
    terms = _stage_terms(stage, d_in)
    index = {t: i for i, t in enumerate(terms)}
    T = len(terms)
    xm, xs, ref, wres, bias, lin, mlp, offsets, hidden, members = ([] for _ in range(10))
    for cell in cells:
        mx = np.asarray(cell["x_norm"]["mean"], float)
        sx = np.asarray(cell["x_norm"]["scale"], float)
        my = np.asarray(cell["y_norm"]["mean"], float)
        sy = np.asarray(cell["y_norm"]["scale"], float)
        ms = cell["members"]
        M = len(ms)
        H = len(ms[0]["b1"])
        if any(len(m["b1"]) != H for m in ms):
            raise ModelError("members of one cell with different hidden widths are not "
                             "supported by the Cycles camera", field="stages.cells.members")
        Lbar = np.zeros((4, T))
        b3 = np.zeros(4)
        for m in ms:
            cols = [index[t] for t in member_terms(m, d_in)]
            Lbar[:, cols] += np.asarray(m["L"], float).reshape(4, len(cols)) / M
            b3 += np.asarray(m["b3"], float) / M
        xm.append(mx)
        xs.append(1.0 / sx)
        ref.append(float(cell["x_norm"].get("wavelength_ref_nm", 0.0)))
        wres.append(int("w_residual_column" in cell["x_norm"]))
        bias.append(my + sy * b3)
        lin.append(sy[:, None] * Lbar)
        hidden.append(H)
        members.append(M)
        for m in ms:
            offsets.append(sum(len(a) for a in mlp))
            W1 = np.asarray(m["W1"], float)
            W2 = np.asarray(m["W2"], float)
            W3 = np.asarray(m["W3"], float) * (sy[:, None] / M)
            mlp.append(np.concatenate([np.column_stack([np.asarray(m["b1"], float), W1]).ravel(),
                                       np.column_stack([np.asarray(m["b2"], float), W2]).ravel(),
                                       W3.ravel()]))
    # a sparse skip (explicit skip_terms, the mirror-symmetric parity split) leaves most
    # (output, monomial) pairs zero: the shader runs each output's loop over its own range
    dense = all(np.count_nonzero(a) == a.size for a in lin)
    slots, ranges = _skip_layout(lin, T)
    coef = [a[j, slots[r0:r1]] for a in lin for j, (r0, r1) in enumerate(ranges)]
    return {"xm": np.concatenate(xm), "xs": np.concatenate(xs), "ref": np.array(ref),
            "wres": np.array(wres),
            "bias": np.concatenate(bias), "dense": dense,
            "lin": np.concatenate([a.ravel() for a in lin]),
            "slot": np.argsort(slots), "ranges": ranges, "coef": np.concatenate(coef),
            "mlp": np.concatenate(mlp), "offsets": np.array(offsets),
            "hidden": np.array(hidden), "members": np.array(members), "terms": terms, "T": T}


def _skip_layout(lin: list[np.ndarray], T: int):
    """Where the shader keeps each monomial so that every output's nonzero terms (in any
    cell) are one contiguous range: outputs whose terms overlap share a range (the parity
    split gives two, the even outputs' and the odd ones'), the monomials no output uses
    (prefixes) last. (slots: the monomial at each place, in build order within a range;
    ranges: [start, stop) per output)."""
    support = [set(np.flatnonzero(np.any([a[j] != 0 for a in lin], axis=0))) for j in range(4)]
    classes: list[tuple[list[int], set]] = []
    for j in range(4):
        joined = [c for c in classes if c[1] & support[j]]
        outputs = [j] + [o for c in joined for o in c[0]]
        terms = support[j].union(*(c[1] for c in joined))
        classes = [c for c in classes if c not in joined] + [(sorted(outputs), terms)]
    slots, ranges = [], [(0, 0)] * 4
    for outputs, terms in sorted(classes, key=lambda c: c[0][0]):
        start = len(slots)
        slots += sorted(terms)
        for j in outputs:
            ranges[j] = (start, len(slots)) if support[j] else (0, 0)
    used = set(slots)
    return np.array(slots + [i for i in range(T) if i not in used], dtype=int), ranges


def _polynomial_lines(p: dict) -> list[str]:
    """Y = bias + (scale_y mean L) phi: four dot products with the monomials, the coefficients
    in arrays rather than written out as literals (JIT compilation time: see
    docs/cycles-camera.md); a sparse skip's each over its output's range of monomials."""
    T = p["T"]
    if p["dense"]:
        return ["for (int j = 0; j < 4; ++j) {",
                "    float acc = BIAS[cell * 4 + j];",
                f"    int base = (cell * 4 + j) * {T};",
                f"    for (int i = 0; i < {T}; ++i) acc += LIN[base + i] * m[i];",
                "    Y[j] = acc;",
                "}"]
    lengths = [b - a for a, b in p["ranges"]]
    stride = sum(lengths)
    lines = []
    for j, (a, b) in enumerate(p["ranges"]):
        if a == b:
            lines.append(f"Y[{j}] = BIAS[cell * 4 + {j}];")
            continue
        lines += ["{",
                  f"    float acc = BIAS[cell * 4 + {j}];",
                  f"    int base = cell * {stride} + {sum(lengths[:j])};",
                  f"    for (int i = 0; i < {b - a}; ++i) acc += COEF[base + i] * m[{a} + i];",
                  f"    Y[{j}] = acc;",
                  "}"]
    return lines


def _stage_function(k: int, stage: dict, d_in: int, dispersion: bool, wl_range,
                    z_in: float, z_out: float) -> list[str]:
    """OSL `int nl_stage_k(x, y, u, v, w, lambda, ox, oy, ou, ov, ow)`."""
    head = (f"int nl_stage_{k}(float x, float y, float u, float v, float w, float lambda_nm,\n"
            f"                 output float ox, output float oy, output float ou, "
            f"output float ov, output float ow)")
    if stage.get("propagate"):
        return [(f"// Stage {k + 1} ({comment_text(stage['name'])}): no surfaces, free flight to z = "
                f"{z_out:g}."), head, "{",
                "    if (!(w > 0.0)) return 0;",
                f"    float t = {flt(z_out - z_in)} / w;",
                "    ox = x + t * u;", "    oy = y + t * v;",
                "    ou = u;", "    ov = v;", "    ow = w;", "    return 1;", "}"]
    p = _pack_stage(stage, d_in)
    D, T = d_in, p["T"]
    bounds, occ = stage["bounds"], stage["occupancy"]
    words, shape = _occupancy_words(occ)
    olo = np.asarray(occ["lo"], float)
    ohi = np.asarray(occ["hi"], float)
    tree = stage["tree"]
    axis = [nd.get("axis", 0) for nd in tree]
    split = [nd.get("split", 0.0) for nd in tree]
    left = [nd.get("left", 0) for nd in tree]
    right = [nd.get("right", 0) for nd in tree]
    leaf = [nd.get("cell", -1) for nd in tree]
    hmax = int(p["hidden"].max())
    tables = (float_array("LO", bounds["lo"], "domain box of X = (r, u_r, u_t, w[, lambda])")
              + float_array("HI", bounds["hi"])
              + int_array("OCC", words, f"occupancy {shape[0]}x{shape[1]}x{shape[2]} over "
                                        f"(r, u_r, u_t), {OCC_BITS_PER_INT} bits per int")
              + int_array("AXIS", axis, "kd-tree: split axis, value, children, leaf cell (-1: "
                                        "inner node)")
              + float_array("SPLIT", split) + int_array("LEFT", left)
              + int_array("RIGHT", right) + int_array("LEAF", leaf)
              + float_array("XM", p["xm"], "per cell: input mean, 1 / input scale")
              + float_array("XS", p["xs"])
              + float_array("BIAS", p["bias"], "per cell: mean_y + scale_y mean(b3)")
              + (float_array("LIN", p["lin"], f"per cell: scale_y mean(L), 4 x {T} monomials")
                 if p["dense"] else
                 float_array("COEF", p["coef"], "per cell and output: scale_y mean(L) over "
                                                "the output's range of monomials")
                 if p["coef"].size else [])
              + float_array("MLP", p["mlp"], "per member: [b1 W1], [b2 W2], (scale_y / M) W3")
              + int_array("MOFF", p["offsets"], "offset of each member in MLP")
              + int_array("HID", p["hidden"], "hidden width per cell")
              + int_array("NMEM", p["members"], "members per cell"))
    mono = []
    place = {}                                  # a monomial's place in m (_skip_layout)
    for t, at in zip(p["terms"], p["slot"]):
        place[t] = at
        src = f"xn[{t[0]}]" if len(t) == 1 else f"m[{place[t[:-1]]}] * xn[{t[-1]}]"
        mono.append(f"m[{at}] = {src};")
    member_offsets = np.concatenate([[0], np.cumsum(p["members"])])
    body = [
        "// radial frame",
        "float r = sqrt(x * x + y * y);",
        "float c = 1.0;",
        "float s = 0.0;",
        "if (r > 0.0) { c = x / r; s = y / r; }",
        f"float X[{D}];",
        "X[0] = r;", "X[1] = c * u + s * v;", "X[2] = c * v - s * u;", "X[3] = w;",
    ] + (["X[4] = lambda_nm;"] if D == 5 else []) + [
        "// learned domain: box, then occupancy cell",
        f"for (int i = 0; i < {D}; ++i)",
        "    if (!(X[i] >= LO[i] && X[i] <= HI[i])) return 0;",
    ]
    if dispersion:
        body += [(f"if (!(lambda_nm >= {flt(wl_range[0])} && lambda_nm <= {flt(wl_range[1])})) "
                 f"return 0;")]
    body += [
        "int flat = 0;",
        f"int SHAPE[3] = {{{shape[0]}, {shape[1]}, {shape[2]}}};",
        f"float OLO[3] = {{{flt(olo[0])}, {flt(olo[1])}, {flt(olo[2])}}};",
        "float OSC[3] = {" + ", ".join(flt(shape[i] / (ohi[i] - olo[i])) for i in range(3))
        + "};",
        "for (int i = 0; i < 3; ++i) {",
        "    float f = (X[i] - OLO[i]) * OSC[i];",
        "    if (!(f >= 0.0 && f <= SHAPE[i])) return 0;",
        "    flat = flat * SHAPE[i] + min((int)f, SHAPE[i] - 1);",
        "}",
        (f"if (((OCC[flat / {OCC_BITS_PER_INT}] >> (flat % {OCC_BITS_PER_INT})) & 1) == 0) "
        f"return 0;"),
        "// kd-tree to the leaf cell",
        "int node = 0;",
        f"for (int i = 0; i < {len(tree)}; ++i) {{",
        "    if (LEAF[node] >= 0) break;",
        "    node = X[AXIS[node]] < SPLIT[node] ? LEFT[node] : RIGHT[node];",
        "}",
        "int cell = LEAF[node];",
        "if (cell < 0) return 0;",
        f"float xn[{D}];",
        f"for (int i = 0; i < {D}; ++i) xn[i] = (X[i] - XM[cell * {D} + i]) * XS[cell * {D} + i];",
    ]
    if p["wres"].any():
        # the cell sees w as its residual (neural.reference.w_residual); the radial frame's w
        # is X[3], its directions X[1], X[2]
        tables += int_array("WRES", p["wres"], "per cell: 1 where w is seen as its residual")
        body += [
            "if (WRES[cell]) {",
            "    float q = X[1] * X[1] + X[2] * X[2];",
            "    float w1 = 1.0 + X[3];",
            "    float wr = -q * q * q * (X[3] + 3.0) / (8.0 * w1 * w1 * w1);",
            f"    xn[3] = (wr - XM[cell * {D} + 3]) * XS[cell * {D} + 3];",
            "}",
        ]
    if p["ref"].any():
        # the cell sees the wavelength as mu = (l0 / lambda)^2 (neural.reference.cell_features)
        tables += float_array("REF", p["ref"], "per cell: reference wavelength (nm) of mu")
        body += [
            "if (REF[cell] > 0.0) {",
            f"    float mu = REF[cell] / X[{D - 1}];",
            f"    xn[{D - 1}] = (mu * mu - XM[cell * {D} + {D - 1}]) * XS[cell * {D} + {D - 1}];",
            "}",
        ]
    body += [
        f"// polynomial skip: {T} monomials of degree 1..{max(len(t) for t in p['terms'])}",
        f"float m[{T}];",
    ] + mono + [
        "float Y[4];",
    ] + _polynomial_lines(p) + [
        "// ensemble members: two tanh layers, the averaged linear output",
        "int H = HID[cell];",
        "int first = " + ("0" if len(member_offsets) == 2 else
                          "MFIRST[cell]") + ";",
        "for (int e = 0; e < NMEM[cell]; ++e) {",
        "    int o = MOFF[first + e];",
        f"    float h1[{hmax}];",
        f"    float h2[{hmax}];",
        "    for (int a = 0; a < H; ++a) {",
        f"        int row = o + a * {D + 1};",
        "        float acc = MLP[row];",
        f"        for (int i = 0; i < {D}; ++i) acc += MLP[row + 1 + i] * xn[i];",
        "        h1[a] = tanh(acc);",
        "    }",
        f"    int o2 = o + H * {D + 1};",
        "    for (int a = 0; a < H; ++a) {",
        "        int row = o2 + a * (H + 1);",
        "        float acc = MLP[row];",
        "        for (int b = 0; b < H; ++b) acc += MLP[row + 1 + b] * h1[b];",
        "        h2[a] = tanh(acc);",
        "    }",
        "    int o3 = o2 + H * (H + 1);",
        "    for (int j = 0; j < 4; ++j) {",
        "        float acc = 0.0;",
        "        for (int a = 0; a < H; ++a) acc += MLP[o3 + j * H + a] * h2[a];",
        "        Y[j] += acc;",
        "    }",
        "}",
        "// back to lens space",
        "ox = c * Y[0] - s * Y[1];",
        "oy = s * Y[0] + c * Y[1];",
        "ou = c * Y[2] - s * Y[3];",
        "ov = s * Y[2] + c * Y[3];",
        "float w2 = 1.0 - ou * ou - ov * ov;",
        "if (!(w2 >= 0.0)) return 0;",
        "ow = sqrt(w2);",
        "return 1;",
    ]
    if len(member_offsets) != 2:
        tables += int_array("MFIRST", member_offsets[:-1], "first member of each cell")
    cells = len(stage["cells"])
    return ([(f"// Stage {k + 1} ({comment_text(stage['name'])}): {cells} cell(s), kd-tree of {len(tree)} "
             f"node(s), hidden width {hmax}, {T} monomials; plane z {z_in:g} -> {z_out:g}."),
             head, "{"] + indent(tables) + indent(body) + ["}"])


def generate_learned(spec) -> str:
    model = load_model(spec)
    meta = model.meta
    lens = spec.lens
    planes = meta["planes"]
    dom = meta["domain"]
    model_disp = bool(dom["dispersion"])
    d_in = 5 if model_disp else 4
    if spec.dispersion and not model_disp:       # the model ignores wavelength: no colours
        spec = dataclasses.replace(spec, dispersion=False)
    aperture = shader_shape(spec.aperture)
    state = lens_state(spec)
    z1, zs, z2 = (float(planes[k]) for k in ("input_z", "stop_z", "output_z"))
    no_stop = "stop_radius_mm" in planes and planes["stop_radius_mm"] is None
    wl = dom["wavelength_range_nm"]
    functions = inside_osl(aperture) + [""] + state.functions + [""]
    functions += _stage_function(0, meta["stages"][0], d_in, model_disp, wl, z1, zs) + [""]
    functions += _stage_function(1, meta["stages"][1], d_in, model_disp, wl, zs, z2) + [""]
    body = state.lines + [
        "// free flight to the input plane Pi_1",
        (f"float t1 = {flt(z1 - spec.sensor_z_mm)} / d[2];" if spec.follow is None else
         f"float t1 = ({flt(z1)} - {state.sensor_z}) / d[2];"),
        "float x1 = sx + t1 * d[0];",
        "float y1 = sy + t1 * d[1];",
        "float xs = 0.0, ys = 0.0, us = 0.0, vs = 0.0, ws = 0.0;",
        "if (!nl_stage_0(x1, y1, d[0], d[1], d[2], lambda_nm, xs, ys, us, vs, ws)) return;",
    ] + ([] if no_stop else [
        "// the stop, exactly, on the stop plane",
        f"if (!nl_inside_stop(xs * {state.inv_stop_radius}, ys * {state.inv_stop_radius})) "
        "return;",
    ]) + [
        "float xo = 0.0, yo = 0.0, uo = 0.0, vo = 0.0, wo = 0.0;",
        "if (!nl_stage_1(xs, ys, us, vs, ws, lambda_nm, xo, yo, uo, vo, wo)) return;",
        f"lp = point(xo, yo, {flt(z2)});",
        "ld = vector(uo, vo, wo);",
    ]
    if spec.ghosts is not None:
        functions, body = with_ghosts(spec, state, functions, body)
    efl = lens.efl_mm if getattr(lens, "table", False) else paraxial_data(lens).efl_mm
    header = [(f"NeuroLens learned lens: model {model.name} for {lens.name} "
              f"(content hash {lens.content_hash()})"),
              (f"planes: Pi_1 z {z1:g}, stop z {zs:g}, Pi_2 z {z2:g} (mm); model dispersion "
              f"{'on' if model_disp else 'off'}; {state.describe}, aperture {aperture!r}"),
              (f"trained sensor z range {dom['sensor_z_range'][0]:.4g} "
              f"to {dom['sensor_z_range'][1]:.4g}), film {spec.sensor_width_mm:g} x "
              f"{spec.sensor_height_mm:g} mm, dispersion {'on' if spec.dispersion else 'off'}")]
    return assemble(spec, header, functions, body, origin_z=state.sensor_z,
                    focal_mm=abs(efl))
