"""Emit a derived filter as a self-contained C99 library, build it, drive it from Python.

:func:`emit_c` writes the files of one filter (``<prefix>`` defaults to ``<model>_<kind>``):

* ``<prefix>_kernel.c/.h``: the step ``<prefix>_kernel``, in one of two styles:

  - ``unrolled``: CasADi's generated code of ``filt.step``, one flat sequence of
    scalar operations (fastest for small models; its size grows as n³);
  - ``loops`` (UKF and SKI): the filter algebra of ``kernel_loops.c.in`` as loops
    over compile-time sizes, calling the model functions f, h and the input-history
    shift that CasADi generates into ``<prefix>_model.c/.h``.

  CasADi's helpers are made ``static`` and every global symbol is prefixed; in float
  builds every maths call and literal is rewritten to single precision.
* ``<prefix>.h/.c``: the step API (state and settings structs, index macros, init,
  reset, the step under the recovery policy of :mod:`skigen.guard`, std) from the
  templates ``filter.h.in`` / ``filter.c.in`` beside this module; it is the same
  for both styles. Both kernels are the derived step's tunable form
  (``filt.tunable``): Q, R and the declared parameters come from ``st.settings``.

:func:`compile_shared` builds (and caches) a shared library; :class:`CFilter`
runs it through ctypes; :func:`load_c` does all three (it is the C backend of
:func:`skigen.runtime.run`).
"""
from __future__ import annotations

import ctypes
import dataclasses
import enum
import functools
import hashlib
import os
import re
import shlex
import shutil
import string
import subprocess
import tempfile
from pathlib import Path

import casadi as ca
import numpy as np

from ..derive import DerivedFilter
from ..derive import TUNABLE
from ..derive.ski import bounded_by_prior, random_walk_weights
from ..guard import Guard
from ..model import function_name_problem

__all__ = ["DEFAULT_FLAGS", "LOOPS_KINDS", "STYLES", "CFilter", "CompileError", "Status",
           "check_prefix", "choose_style", "compile_shared", "default_prefix", "emit_c", "load_c"]

REALS = {"double": (ctypes.c_double, np.float64), "float": (ctypes.c_float, np.float32)}
DEFAULT_FLAGS = ("-std=c99", "-Wall", "-Wextra", "-pedantic", "-Werror", "-O2")
_HERE = Path(__file__).parent
# C99 <math.h> functions CasADi may call; float builds use their f-suffixed forms.
_MATH = ("sqrt cbrt exp expm1 log log1p log2 log10 pow fabs fmax fmin fmod floor ceil round trunc "
         "copysign hypot erf erfc sin cos tan asin acos atan atan2 sinh cosh tanh asinh acosh atanh")
_MATH_RE = re.compile(r"\b(%s)\(" % "|".join(_MATH.split()))
_LITERAL_RE = re.compile(r"(?<![\w.])(\d+\.\d*(?:[eE][+-]?\d+)?|\d+[eE][+-]?\d+)(?![\w.])")
STYLES = ("auto", "unrolled", "loops")
LOOPS_KINDS = ("ukf", "ski")        # kinds the looped kernel implements
AUTO_LOOPS_ABOVE_OPERATIONS = 20_000   # 'auto' loops above this many unrolled operations
# (about 170 kB of Cortex-M7 code at the ~8.5 bytes per operation `skigen bench footprint` measures;
# the looped kernel stays 30-60 kB at any size)
_UPDATES = {"z": "z_next", "C": "C_next", "s": "s_next", "mem": "mem_next"}   # committed on success
_C0_BOUND = ("; 3 when its weight block is not within the ARD prior, P_ww <= diag(s0)\n"
             " * (the EM update's bound: updates only shrink P_ww; restart with the weights' rows of a saved\n"
             " * posterior, or scale them down; C_next, a scratch, is used)")
_Q_BOUND = (", or an entry in a weight's row:\n"
            " * the EM update was generated for constant weights, which keep P_ww <= diag(s0)")
_FOH_NOTE = (" * First-order input hold: u holds u_k then u_{k+1} (NU values), and the prediction\n"
             " * interpolates the input linearly between them. On a vehicle, where u_{k+1} is known\n"
             " * one sample later, call the step one sample late: step(u_k, u_{k+1}, y_k) at time k+1.\n")
_LOCALS = {"u": "u", "y": "yv", "valid": "valid",                          # step inputs not in the state
           **{k: f"st->settings.{k}" for k in ("Q_sqrt", "R_sqrt", "param")}}


class Status(enum.IntEnum):
    """Return codes of ``<prefix>_step`` (the ``skigen_status`` enum of the header)."""

    OK = 0
    MEASUREMENT_SKIPPED = 1
    BAD_INPUT = 2
    NUMERICAL_FAILURE = 3
    OUTLIER_REJECTED = 4
    SENSOR_STUCK = 5
    REINITIALISED = 6
    BAD_SETTINGS = 7


class CompileError(RuntimeError):
    """The C compiler failed; the message holds its command and output."""


def default_prefix(filt: DerivedFilter) -> str:
    return f"{filt.aug.model.name}_{filt.kind}"


def _fields(filt: DerivedFilter) -> list[tuple[str, tuple, str]]:
    """The real-valued fields of ``<prefix>_state`` in order: (name, shape, comment).

    The int/real work buffers ``iw`` and ``w`` follow them, last, in the struct.
    """
    d, ski = filt.aug.shapes, filt.has_ard
    n, ny, nw, nmem = d["n"], d["ny"], d["nw"], d["nmem"]
    cov = "lower Cholesky factor S" if filt.square_root else "covariance P"
    rows = [("z", (n,), "prior mean for the next sample"),
            ("C", (n, n), f"prior {cov} for the next sample"),
            ("s", (nw,), "ARD prior variances of the weights"),
            ("mem", (nmem,), "input history"),
            ("z_post", (n,), "posterior mean at the last sample"),
            ("C_post", (n, n), f"posterior {cov} at the last sample"),
            ("e", (ny,), "innovation y - h(z) (0 where skipped)"),
            ("Pyy", (ny, ny), "innovation covariance"),
            ("nis", (), "normalised innovation squared"),
            ("loglik", (), "log-likelihood of the measurement"),
            ("used", (ny,), "1 where y[i] updated the state at the last sample, else 0"),
            ("y_last", (ny,), "last finite reading of each output (stuck-sensor check)"),
            ("u_held", (d["nu"],), "last finite value of each input, used where one is not"),
            ("z_next", (n,), "scratch: kernel results awaiting acceptance"),
            ("C_next", (n, n), "scratch"),
            ("s_next", (nw,), "scratch"),
            ("mem_next", (nmem,), "scratch")]
    return [r for r in rows if ski or r[0] not in ("s", "s_next")]


def _settings(filt: DerivedFilter) -> list[tuple[str, str, tuple, str]]:
    """The fields of ``<prefix>_settings``: (name, 'real' or 'long', shape, comment); see skigen.guard."""
    n, ny, npar = filt.aug.n, filt.aug.shapes["ny"], filt.aug.fixed.shape[0]
    return [("Q_sqrt", "real", (n, n), "lower factor of the process noise over the whole state z (the _Z_ "
             "macros: states, weights, estimated parameters), Q = Q_sqrt Q_sqrt^T (upper ignored)"),
            ("R_sqrt", "real", (ny, ny), "lower factor of the measurement noise, R = R_sqrt R_sqrt^T (its signs free)"),
            ("param", "real", (npar,), "declared parameters not estimated (an estimated one is in z), see the _P_ "
             "index macros"),
            ("gate", "real", (), "innovation gate per output, in standard deviations (0: off)"),
            ("reinit_scale", "real", (), "variance multiple of the declared initial covariance at a restart"),
            ("std_max", "real", (n,), "bound on each prior standard deviation (settings_init: a multiple of "
             "the declared initial one, 100 by default; INFINITY: none)"),
            ("reject_limit", "long", (), "readings of an output rejected in a row before its next one restarts the states (0: never)"),
            ("gap_limit", "long", (), "samples without a used measurement after which a reading the gate rejects restarts (0: never)"),
            ("stuck_limit", "long", (), "identical readings in a row from which an output is stuck (0: off)")]


def _health(filt: DerivedFilter) -> list[tuple[str, tuple, str]]:
    """The counters (``long``) of ``<prefix>_state`` after its settings: (name, shape, comment)."""
    ny, n = filt.aug.shapes["ny"], filt.aug.n
    return [("rejected", (ny,), "measurements rejected by the gate, per output, in total"),
            ("stuck", (ny,), "readings not used as stuck, per output, in total"),
            ("repeats", (ny,), "identical readings in a row so far, per output"),
            ("reinits", (), "restarts of the physical states (recovery), in total"),
            ("reject_run", (ny,), "readings in a row rejected (gated or a failed step), per output"),
            ("since_update", (), "samples since a measurement was last used"),
            ("bounded", (n,), "prior stds held at settings.std_max, per state, in total")]


def _size(shape: tuple) -> int:
    return int(np.prod(shape, dtype=int))


def _literal(x: float, real: str) -> str:
    if x == np.inf:
        return "INFINITY"
    if not np.isfinite(x):
        raise ValueError(f"non-finite initial value {x}")
    return repr(float(x)) + ("f" if real == "float" else "")   # shortest round-trip form


def _c_strings(names) -> str:
    return ", ".join(f'"{s}"' for s in names) or "0"


def _index_macros(filt: DerivedFilter, PREFIX: str) -> str:
    """``#define <PREFIX>_Z_<NAME> i`` for every state and weight, likewise U_ inputs, Y_ outputs
    and P_ declared parameters (of ``settings.param``), each with its declared unit (a weight:
    the term it multiplies and the equation whose rate, or next value in a discrete model, it enters)."""
    model = filt.aug.model
    groups = {"Z": filt.aug.names, "U": filt.aug.u_names, "Y": model.output_names, "P": filt.aug.fixed_names}
    units = {v.name: v.unit for v in [*model.states, *model.inputs, *model.outputs, *model.parameters]}
    enters = "the next value" if model.discretization == "discrete" else "the rate"
    units |= {w: f"times {t.name} in {enters} of {eq.replace('+', ' and ')}" for w, eq, t, _ in model.weights()}
    lines, seen = [], {}
    for tag, names in groups.items():
        for i, name in enumerate(names):
            macro = f"{PREFIX}_{tag}_{name.upper()}"
            if macro in seen:
                raise ValueError(f"names '{seen[macro]}' and '{name}' both give the C macro {macro}: "
                                 f"rename one (index macros are upper case)")
            seen[macro] = name
            unit = units.get(name, "").replace("*/", "* /")     # never ends the comment
            lines.append(f"#define {macro} {i}" + (f" /* {unit} */" if unit else ""))
    return "\n".join(lines) + "\n"


def choose_style(filt: DerivedFilter, style: str = "auto") -> str:
    """The kernel style emitted for ``style``: 'auto' unrolls a step of up to
    :data:`AUTO_LOOPS_ABOVE_OPERATIONS` scalar operations and loops (where the kind allows
    it) above: the unrolled code grows as n³ and soon outgrows a flight computer's flash."""
    if style not in STYLES:
        raise ValueError(f"style must be one of {', '.join(STYLES)}, got '{style}'")
    if style == "auto":
        large = filt.kind in LOOPS_KINDS and filt.tunable.n_instructions() > AUTO_LOOPS_ABOVE_OPERATIONS
        return "loops" if large else "unrolled"
    if style == "loops" and filt.kind not in LOOPS_KINDS:
        raise ValueError(f"the looped kernel implements {', '.join(LOOPS_KINDS)}; "
                         f"emit filter '{filt.kind}' with style 'unrolled'")
    return style


def _casadi_code(functions, name: str, real: str, stamp: str) -> tuple[str, str, dict[str, int]]:
    """CasADi's code of ``functions`` in one file ``name``.c/.h: (c text, h text, work sizes,
    the largest over the functions)."""
    cg = ca.CodeGenerator(f"{name}.c", {"with_header": True, "casadi_real": real, "casadi_int": "int",
                                        "prefix": name, "with_mem": False, "with_export": False})
    for f in functions:
        cg.add(f)
    with tempfile.TemporaryDirectory() as tmp:
        cg.generate(tmp + os.sep)
        c, h = (Path(tmp, name + ext).read_text() for ext in (".c", ".h"))
    sizes = {k: max(int(v) for v in re.findall(rf"#define \w+_SZ_{k.upper()} (\d+)", h))
             for k in ("arg", "res", "iw", "w")}
    return stamp + _tidy(c, name, real), stamp + _guarded(h, name, real), sizes


def _guarded(h: str, name: str, real: str) -> str:
    """CasADi's header with an include guard and its types written out: its ``casadi_real`` macro
    would leak into the includer, and a double and a float model header in one file gave the
    second's prototypes the first's type."""
    h = re.sub(r"#ifndef (casadi_real|casadi_int)\n#define \1 \w+\n#endif\n\n", "", h)
    h = re.sub(r"\bcasadi_real\b", real, re.sub(r"\bcasadi_int\b", "int", h))
    guard = f"{name.upper()}_H"
    return f"#ifndef {guard}\n#define {guard}\n{h}#endif /* {guard} */\n"


def _kernel(filt: DerivedFilter, prefix: str, real: str) -> tuple[dict[str, str], dict[str, int]]:
    """The unrolled step: CasADi's code of ``filt.tunable`` as ``<prefix>_kernel``."""
    step, name = filt.tunable, f"{prefix}_kernel"
    f = ca.Function(name, step.sx_in(), step.call(step.sx_in()), step.name_in(), step.name_out())
    stamp = f"/* {name}: {filt.kind} step of model '{filt.aug.model.name}' ({real}), generated by skigen. */\n"
    c, h, sizes = _casadi_code([f], name, real, stamp)
    return {f"{name}.c": c, f"{name}.h": h}, sizes


def _work_layout(n: int, ny: int, nw: int, nq: int, model_w: int, em: bool = False) -> tuple[str, int]:
    """Pointers carving the looped kernel's buffers from ``w`` (C text) and the reals needed.

    The first group lives through the step; the UKF's scratch and the ARD's (nw > 0)
    are never live together, so they share the memory after it.
    """
    nsig = 2 * n + 1
    groups = [[("X", n * nsig), ("Y", ny * nsig), ("Sy", ny * ny), ("y_hat", ny), ("noise", 2 * ny * ny),
               ("K", ny * n), ("x_col", n), ("a_col", ny), ("model_w", max(model_w, 1))],
              [("Xf", n * nsig), ("A", max((2 * n + 2 * ny) * ny, (2 * n + nq) * n))]]
    if nw:   # F_ww, then the larger of ard_optimise's (3 nw + ard_grad's) and ard_correct's scratch,
        grad = 2 * nw + 2 * n * n + n + n * nw                       # or ard_em's
        work = (n + nw + 3 * nw + 2 * n * n + 2 * n + n * nw if em else
                max(3 * nw + grad, 3 * nw + 3 * n * n + 2 * n))
        groups.append([("F_ww", nw * n), ("ard_work", work)])
    lines, base = [], sum(size for _, size in groups[0])
    for group, start in zip(groups, [0] + [base] * (len(groups) - 1)):
        for name, size in group:
            lines.append(f"    real* {name} = w + {start};")
            start += size
    return "\n".join(lines), base + max(sum(size for _, size in g) for g in groups[1:])


def _kernel_loops(filt: DerivedFilter, prefix: str, real: str) -> tuple[dict[str, str], dict[str, int]]:
    """The looped step: ``kernel_loops.c.in`` around CasADi's code of f, h and the
    input-history shift (``<prefix>_model.c/.h``)."""
    from ..derive.ukf import merwe_weights

    aug, opts, d = filt.aug, filt.options, filt.aug.shapes
    n, ny, nw, ard = d["n"], d["ny"], d["nw"], int(filt.has_ard)
    model = f"{prefix}_model"
    zum = [aug.z, aug.u, aug.mem, aug.fixed]
    f, h = (aug.f if aug.f_free is None else aug.f_free), (aug.h if aug.h_free is None else aug.h_free)
    functions = [ca.Function(f"{model}_f", zum, [ca.densify(f)]),
                 ca.Function(f"{model}_h", zum, [ca.densify(h)])]
    if d["nmem"]:
        functions.append(ca.Function(f"{model}_mem_next", [aug.u, aug.mem], [ca.densify(aug.mem_next)]))
    stamp = f"/* {model}: model functions of '{aug.model.name}' ({real}), generated by skigen. */\n"
    mc, mh, msz = _casadi_code(functions, model, real, stamp)
    Wm, Wc, gamma = merwe_weights(n, opts.alpha, opts.beta, opts.kappa)
    lit = lambda x: _literal(x, real)
    array = lambda a: ", ".join(lit(x) for x in np.ravel(a, order="F")) or lit(0.0)
    em = ard and opts.ard == "em"
    work, work_size = _work_layout(n, ny, nw if ard else 0, n, msz["w"], em)
    # Q, R and the parameters are run-time settings (arg[ARD + 6..8]), but the EM update's
    # ARD_DRIFT (random-walk weights, decided from the declared numeric Q_w here) and its
    # declared prior S0 stay generation-time constants: a Q_sqrt set at run time that gives
    # constant weights a random walk is refused by <prefix>_settings_check.
    drift = int(random_walk_weights(aug))
    values = dict(
        prefix=prefix, kind=filt.kind, model=aug.model.name, real=real, N=n, NX=d["nx"], NW=nw, NY=ny,
        NMEM=d["nmem"], ARD=ard, ARD_STEPS=opts.ard_steps, BACKTRACKS=opts.backtracks,
        WM0=lit(Wm[0]), WM1=lit(Wm[1]), WC0=lit(Wc[0]), WC1=lit(Wc[1]), SQRT_WC1=lit(np.sqrt(Wc[1])),
        SQRT_WC0=lit(np.sqrt(abs(Wc[0]))), WC0_SIGN=lit(np.sign(Wc[0])), GAMMA=lit(gamma),
        LOG_2PI=lit(np.log(2 * np.pi)), ETA=lit(opts.eta), MAX_STEP=lit(opts.max_step),
        MARGIN=lit(opts.margin), S_MIN=lit(opts.s_min), S_MAX=lit(opts.s_max), ARD_EM=int(em),
        ARD_DRIFT=drift, S_FLOOR=lit(opts.s_floor), S0=array(aug.s0), work=work)
    kc = string.Template((_HERE / "kernel_loops.c.in").read_text()).substitute(values)
    if real == "float":
        kc = _single_precision(kc)
    name, guard = f"{prefix}_kernel", f"{prefix.upper()}_KERNEL_H"
    sizes = dict(arg=len(filt.names_in) + len(TUNABLE), res=len(filt.names_out), iw=msz["iw"], w=work_size)
    kh = (f"/* {name}.h: {filt.kind} step of model '{aug.model.name}' ({real}), the filter algebra as "
          f"loops, generated by skigen. */\n#ifndef {guard}\n#define {guard}\n\n"
          + "".join(f"#define {name}_SZ_{k.upper()} {v}\n" for k, v in sizes.items())
          + f"\nint {name}(const {real}** arg, {real}** res, int* iw, {real}* w, int mem);\n\n#endif\n")
    return {f"{name}.c": kc, f"{name}.h": kh, f"{model}.c": mc, f"{model}.h": mh}, sizes


FLOAT_S_FLOOR = 1e-4   # EM's ARD floor in float builds: the correction's condition ~ m / s_floor
FLOAT_SPAN = 1e3       # a state whose declared mean is this many declared std from 0 loses its spread in float


def float_precision(filt: DerivedFilter) -> str | None:
    """Why a float build of ``filt`` may drift from the double one: the augmented states whose
    declared mean is more than FLOAT_SPAN of their declared std (float keeps ~7 digits; a position
    500 km from its origin with a 0.3 m std lost its sigma points' spread and diverged with every
    step's code normal); None when there is none."""
    aug = filt.aug
    sd = np.sqrt(np.diag(aug.P0))
    span = np.abs(aug.z0) / np.where(sd > 0, sd, np.inf)
    far = np.flatnonzero(span > FLOAT_SPAN)
    if not far.size:
        return None
    i = far[np.argmax(span[far])]
    return (f"in float, {', '.join(repr(aug.names[j]) for j in far)} start{'s' if len(far) == 1 else ''} more than "
            f"{FLOAT_SPAN:g} declared std from 0 ('{aug.names[i]}' at {aug.z0[i]:.4g} with std {sd[i]:.2g}): float "
            f"keeps about 7 significant digits, so its rounding there, {abs(aug.z0[i]) * 2.0 ** -24:.2g}, is "
            f"{abs(aug.z0[i]) * 2.0 ** -24 / sd[i]:.2g} of the std at the start and more once the filter "
            f"narrows it: the estimate can drift from the double build's with every step's code normal. "
            f"Write the state relative to a nearby reference (the first fix, a local origin), or build in double")


def single_precision_options(filt: DerivedFilter) -> DerivedFilter:
    """``filt`` as float builds run it: the EM update's floor raised to :data:`FLOAT_S_FLOOR`,
    so that the ARD correction stays well conditioned in single precision."""
    o = filt.options
    if not filt.has_ard or o.ard != "em" or o.s_floor >= FLOAT_S_FLOOR:
        return filt
    return dataclasses.replace(filt, options=dataclasses.replace(o, s_floor=FLOAT_S_FLOOR))


def _tidy(c: str, name: str, real: str) -> str:
    """Make CasADi's C strict-C99 clean, helpers static, float builds single precision."""
    # Check the definitions against the header's prototypes.
    c = c.replace("#include <math.h>\n", f'#include <math.h>\n#include "{name}.h"\n', 1)
    # Helpers like `casadi_real casadi_sq(...)` are file-local.
    c = re.sub(r"^(casadi_real|casadi_int|int|void) (casadi_\w+\()", r"static \1 \2", c, flags=re.M)
    # Silence unused-parameter warnings of the entry points (SX code uses no iw, w, mem).
    def void_casts(m):
        params = [p.replace("*", " ").split()[-1] for p in m.group(1).split(",") if p.strip() != "void"]
        return m.group(0) + "".join(f"\n  (void){p};" for p in params if p in ("iw", "w", "mem"))
    c = re.sub(r"^[^\s#/][^;\n]*\b\w+\(([^()]*)\)\s*\{", void_casts, c, flags=re.M)
    return _single_precision(c) if real == "float" else c


_STATIC_RE = re.compile(r"^static\s+(?:inline\s+)?(?:const\s+)?\w+\s*\**\s*(\w+)\s*[\[(=;]", re.M)
_MORE_RE = re.compile(r"^static\s+const\s+\w+\s+\w+\s*=[^;\n]*?((?:,\s*\w+\s*=[^,;\n]*)+);", re.M)
_TYPEDEF_RE = re.compile(r"^typedef\s+[^;]*?\b(\w+)\s*;", re.M)
_DEFINE_RE = re.compile(r"^\s*#\s*define\s+(\w+)", re.M)


def _file_local(c: str, prefix: str) -> str:
    """C text whose file-scope names (statics, typedefs) are ``<prefix>_l_<name>`` (``prefix``: the
    file's name) by macros after
    its includes, and whose macros are undefined at its end: several generated files compile as
    one translation unit (a unity build), each keeping its own ``real``, ``copy_n`` and CasADi's
    ``casadi_real`` (a float kernel after a double one took its type)."""
    macros = list(dict.fromkeys(_DEFINE_RE.findall(c)))
    names = _TYPEDEF_RE.findall(c) + _STATIC_RE.findall(c)
    for more in _MORE_RE.findall(c):
        names += re.findall(r",\s*(\w+)\s*=", more)
    names = [n for n in dict.fromkeys(names) if n not in macros]
    if not names and not macros:
        return c
    local = "".join(f"#define {n} {prefix}_l_{n}\n" for n in names)
    if local:
        last = max(m.end() for m in re.finditer(r"^#include .*\n", c, re.M))
        c = (c[:last] + "\n/* file-local names, prefixed: several generated files build as one unit */\n"
             + local + c[last:])
    return c.rstrip("\n") + "\n\n" + "".join(f"#undef {n}\n" for n in names + macros)


def _single_precision(c: str) -> str:
    """Every maths call and floating literal of C text in its float form (sqrtf, 0.5f)."""
    return _LITERAL_RE.sub(r"\1f", _MATH_RE.sub(r"\1f(", c))


# The C standard library's headers (C99/C11): a generated <prefix>.h named like one hides it.
STANDARD_HEADERS = frozenset("""assert complex ctype errno fenv float inttypes iso646 limits locale math setjmp
    signal stdalign stdarg stdatomic stdbool stddef stdint stdio stdlib stdnoreturn string tgmath threads time
    uchar wchar wctype""".split())


LONGEST_PREFIX = 200    # characters: '<prefix>_kernel.c' and its kin stay under a file name's 255


PART_SUFFIXES = ("_kernel", "_model")      # <prefix>_kernel.[ch], <prefix>_model.[ch]: a filter's other files


def check_prefix(prefix: str) -> str:
    """``prefix``, or ValueError naming the rule it breaks: a C identifier that can begin CasADi
    Function names (``<prefix>_kernel``) and names no standard header (``<prefix>.h``)."""
    if not prefix.isidentifier() or not prefix.isascii():
        raise ValueError(f"prefix '{prefix}' is not a C identifier")
    if prefix in STANDARD_HEADERS or prefix == "main":
        raise ValueError(f"prefix '{prefix}' would name the generated header '{prefix}.h'"
                         + (f" like the standard <{prefix}.h>, which it would hide from the generated code"
                            if prefix != "main" else " and source like a program's entry point")
                         + "; choose another")
    if len(prefix) > LONGEST_PREFIX:
        raise ValueError(f"prefix '{prefix[:20]}…' has {len(prefix)} characters: the files it names "
                         f"('<prefix>_kernel.c') would pass the file system's 255; keep it to {LONGEST_PREFIX}")
    if prefix == "casadi" or prefix.startswith("casadi_"):
        raise ValueError(f"prefix '{prefix}' would name the kernel '{prefix}_kernel', which CasADi's code generator "
                         f"takes for one of its own runtime functions ('casadi_…', made static: the C would not "
                         f"link); choose another")
    if part := next((p for p in PART_SUFFIXES if prefix.endswith(p) and len(prefix) > len(p)), None):
        raise ValueError(f"prefix '{prefix}' would name its files like a part of filter '{prefix[:-len(part)]}' "
                         f"({prefix}.h is that filter's {part[1:]} header): two such filters in one folder or "
                         f"one build overwrite each other or clash; choose another")
    why = function_name_problem(prefix)
    if why:
        raise ValueError(f"prefix '{prefix}' cannot name CasADi Functions: {why}; CasADi's start with a "
                         f"letter and have no two underscores in a row ('{prefix}_kernel'); choose another")
    return prefix


def emit_c(filt: DerivedFilter, out_dir, real: str = "double", prefix: str | None = None,
           style: str = "auto") -> list[Path]:
    """Write ``<prefix>.h/.c`` and the kernel's files to ``out_dir``; return their paths.

    style: 'unrolled', 'loops' or 'auto' (see :func:`choose_style`).
    """
    if real not in REALS:
        raise ValueError(f"real must be one of {', '.join(REALS)}, got '{real}'")
    prefix = check_prefix(prefix or default_prefix(filt))
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    filt = single_precision_options(filt) if real == "float" else filt
    kernel = _kernel_loops if choose_style(filt, style) == "loops" else _kernel
    kernel_files, sz = kernel(filt, prefix, real)
    d = filt.aug.shapes
    fields = {name: shape for name, shape, _ in _fields(filt)}
    dim = lambda shape: "" if shape == () else f"[{max(_size(shape), 1)}]"
    ref = lambda name: f"&st->{name}" if fields[name] == () else f"st->{name}"
    struct = [f"    {prefix}_real {name}{dim(shape)}; /* {doc} */" for name, shape, doc in _fields(filt)]
    struct += [f"    {prefix}_settings settings; /* run-time settings, changeable between steps */"]
    struct += [f"    long {name}{dim(shape)}; /* {doc} */" for name, shape, doc in _health(filt)]
    struct += [f"    int iw[{max(sz['iw'], 1)}]; /* kernel work */",
               f"    {prefix}_real w[{max(sz['w'], 1)}]; /* kernel work */"]
    settings = [f"    {prefix + '_real' if t == 'real' else 'long'} {name}{dim(shape)}; /* {doc} */"
                for name, t, shape, doc in _settings(filt)]
    wiring = [f"    arg[{i}] = {ref(k) if k in fields else _LOCALS[k]};"
              for i, k in enumerate(filt.names_in + list(TUNABLE))]
    wiring += [f"    res[{i}] = {ref(k)};" for i, k in enumerate(filt.names_out)]
    finite = [f"    failed = failed || !all_finite({ref(k)}, {_size(fields[k])});" for k in filt.names_out]
    commit = [f"    copy_n(st->{a}, st->{b}, {_size(fields[a])});" for a, b in _UPDATES.items() if a in fields]
    # Declared values: z, C (column-major), s and the settings' arrays as constants; the rest 0.
    guard = Guard()
    start = {k: np.ravel(v, order="F") for k, v in filt.initial().items()}
    start["std_max"] = guard.std_max(filt.aug.P0)
    start.update({k: np.ravel(v, order="F") for k, v in filt.settings().items()})
    start = {k: v if v.size else np.zeros(1) for k, v in start.items()}
    consts = [f"static const real {k}0[{v.size}] = {{\n    " + ",\n    ".join(
              ", ".join(_literal(x, real) for x in v[i:i + 8]) for i in range(0, v.size, 8)) + "};"
              for k, v in start.items() if np.any(v) or k in ("z", "C") or k in TUNABLE]
    init = []
    for name, shape, _ in _fields(filt):
        if name.endswith("_next") or name.endswith("_post"):
            continue
        if shape == ():
            init.append(f"    st->{name} = 0;")
        elif name in start and (np.any(start[name]) or name in ("z", "C")):
            init.append(f"    copy_n(st->{name}, {name}0, {_size(shape)});")
        else:
            init.append(f"    zero_n(st->{name}, {_size(shape)});")
    init += [f"    zero_l({'&' if shape == () else ''}st->{name}, {max(_size(shape), 1) if shape else 1});"
             for name, shape, _ in _health(filt)]
    settings_init = []
    for name, _, shape, _ in _settings(filt):
        if shape:
            settings_init.append(f"    copy_n(set->{name}, {name}0, {_size(shape)});")
        else:
            settings_init.append(f"    set->{name} = {_literal(getattr(guard, name), real) if isinstance(getattr(guard, name), float) else getattr(guard, name)};")
    model = filt.aug.model
    em_bound = filt.has_ard and bounded_by_prior(filt.aug, filt.options)
    checks = ([("covariance", 2)] if not filt.square_root else []) + ([("within_prior", 3)] if em_bound else [])
    values = dict(
        prefix=prefix, PREFIX=prefix.upper(), real=real, model=model.name,
        kind_long={"ekf": "augmented EKF", "ukf": "augmented square-root UKF",
                   "ski": "SKI (square-root UKF with ARD)", "mukf": "marginalised square-root UKF (MUKF)",
                   "ski_mukf": "SKI on the marginalised UKF (MUKF with ARD)"}[filt.kind],
        s_note=", s" if "s" in fields else "", s_reset=", s at its declared value" if "s" in fields else "",
        c0_rule=(", or (S is lower-triangular) a non-zero entry above the diagonal" if filt.square_root else
                 ", or when it is not symmetric and positive semi-definite (to 100 machine epsilons)"),
        c0_bound=_C0_BOUND if em_bound else "", q_bound=_Q_BOUND if em_bound else "",
        c0_bound_check="".join(f"        if (!{check}(st, C_start)) return {code};\n" for check, code in checks),
        q_bound_check=f" || (i >= {prefix.upper()}_NX && set->Q_sqrt[i + j * n] != 0)" if em_bound else "",
        NPAR=filt.aug.fixed.shape[0],
        DT=_literal(float(model.dt), real), index=_index_macros(filt, prefix.upper()),
        TOL=_literal(100 * np.finfo(np.float32 if real == "float" else float).eps, real),
        N=d["n"], NX=d["nx"], NW=d["nw"], NU=d["nu"], NY=d["ny"], NMEM=d["nmem"],
        NU1=max(d["nu"], 1), NY1=max(d["ny"], 1), SQUARE_ROOT=int(filt.square_root),
        SZ_ARG=max(sz["arg"], 1), SZ_RES=max(sz["res"], 1), SZ_IW=sz["iw"], SZ_W=sz["w"],
        fields="\n".join(struct), wiring="\n".join(wiring), finite="\n".join(finite), commit="\n".join(commit),
        initial="\n".join(consts), init="\n".join(init), sqrt="sqrtf" if real == "float" else "sqrt",
        fabs="fabsf" if real == "float" else "fabs", settings="\n".join(settings),
        settings_init="\n".join(settings_init),
        state_names=_c_strings(filt.aug.names), input_names=_c_strings(filt.aug.u_names),
        hold_note=_FOH_NOTE if model.input_hold == "foh" else "",
        nu_note=" per step: u_k, then u_{k+1} (first-order hold)" if model.input_hold == "foh" else "",
        output_names=_c_strings(v.name for v in model.outputs))
    values["start_checks"] = "".join(string.Template((_HERE / f"{check}.c.in").read_text()).substitute(values)
                                     for check, _ in checks)
    texts = {f"{prefix}.h": string.Template((_HERE / "filter.h.in").read_text()).substitute(values),
             f"{prefix}.c": string.Template((_HERE / "filter.c.in").read_text()).substitute(values),
             **kernel_files}
    texts = {f: _file_local(t, f[:-2]) if f.endswith(".c") else t for f, t in texts.items()}
    return write_whole(out, texts)


def left_over(written: list[Path]) -> list[Path]:
    """Files beside ``written`` named as this filter's parts (``<prefix>.[ch]``, ``<prefix>_kernel.[ch]``,
    ``<prefix>_model.[ch]``) that this generation did not write: a looped kernel's model files
    stayed when the folder was generated again unrolled, dead code in a build of the folder."""
    prefix = written[0].stem
    names = {f"{prefix}{part}{ext}" for part in ("", *PART_SUFFIXES) for ext in (".c", ".h")}
    return sorted(p for p in written[0].parent.iterdir() if p.name in names and p not in written)


def write_whole(out: Path, texts: dict[str, str]) -> list[Path]:
    """Write each ``{file name: text}`` in ``out``, all of them or none: every text is written
    beside its file first and moved into place once all are written. A failure (a full disk)
    removes what it wrote and names the file, not only "[Errno 28] No space left on device"."""
    partial = {out / f: out / f".{f}.partial" for f in texts}
    try:
        for (path, tmp), text in zip(partial.items(), texts.values()):
            try:
                tmp.write_text(text, newline="\n")
            except OSError as exc:
                raise OSError(exc.errno, f"cannot write {path}: {exc.strerror or exc}") from exc
        for path, tmp in partial.items():
            tmp.replace(path)
    finally:
        for tmp in partial.values():
            tmp.unlink(missing_ok=True)
    return list(partial)


@functools.lru_cache(maxsize=None)
def _cc_version(cc: tuple[str, ...]) -> str:
    return subprocess.run([*cc, "--version"], capture_output=True, text=True, check=True).stdout


def _compiler(cc: str | None) -> tuple[str, ...]:
    """The compiler command: ``cc``, else ``$CC``, else gcc; a clear error where it is not found."""
    cmd = tuple(shlex.split(cc or os.environ.get("CC") or "gcc"))
    if not cmd or shutil.which(cmd[0]) is None:
        raise CompileError(f"the c backend needs a C compiler: {' '.join(cmd) or repr(cc)!s} is not on PATH "
                           f"(install gcc, set CC to one, or use --backend python)")
    return cmd


def compile_shared(sources, out=None, cc: str | None = None, flags=DEFAULT_FLAGS, cache_dir=None) -> Path:
    """Build ``sources`` (.c; .h allowed) into a shared library with ``-fPIC -shared ... -lm``; ``cc``
    the compiler command (default ``$CC``, else gcc).

    Libraries are cached by a hash of the compiler, flags and the sources with every header
    beside them, in ``cache_dir`` (default ``$SKIGEN_CACHE`` or ``~/.cache/skigen``).
    Returns ``out`` (a copy of the cached library) or the cached path itself.
    """
    cc = _compiler(cc)
    sources = [Path(s).resolve() for s in sources]
    cfiles = [s for s in sources if s.suffix == ".c"]
    dirs = sorted({s.parent for s in sources})
    hashed = cfiles + sorted({h for d in dirs for h in d.glob("*.h")})
    key = hashlib.sha256("\0".join([*cc, _cc_version(cc), *flags]).encode())
    for p in hashed:
        key.update(b"\0" + p.name.encode() + b"\0" + p.read_bytes())
    cache = Path(cache_dir or os.environ.get("SKIGEN_CACHE") or Path.home() / ".cache" / "skigen")
    lib = cache / "c" / f"{key.hexdigest()[:32]}.so"
    if not lib.exists():
        lib.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(suffix=".so", dir=lib.parent)
        os.close(fd)
        cmd = [*cc, *flags, "-fPIC", "-shared", *(f"-I{d}" for d in dirs), *map(str, cfiles), "-o", tmp, "-lm"]
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode:
            os.unlink(tmp)
            raise CompileError(f"{' '.join(cmd)}\n{r.stdout}{r.stderr}")
        os.replace(tmp, lib)
    if out is None:
        return lib
    shutil.copyfile(lib, out)
    return Path(out)


class CFilter:
    """A compiled filter library run through ctypes; the state lives in a Python-owned buffer.

    Fields of ``<prefix>_state`` read as NumPy arrays (``cf.z``, ``cf.C`` as an n×n matrix,
    ``cf.nis`` as a float) and are written with :meth:`set`.
    """

    def __init__(self, lib_path, filt: DerivedFilter, real: str = "double", prefix: str | None = None):
        ct, self.dtype = REALS[real]
        self.prefix, self.kind, self.n = prefix or default_prefix(filt), filt.kind, filt.aug.n
        self.filt, self.square_root = filt, filt.square_root
        self.shapes = {name: shape for name, shape, _ in _fields(filt)}
        self.counters = {name: shape for name, shape, _ in _health(filt)}
        self.settings = {name: (t, shape) for name, t, shape, _ in _settings(filt)}
        self.lib = ctypes.CDLL(str(Path(lib_path).resolve()))
        array = lambda t, shape: t * max(_size(shape), 1) if shape else t
        types = {"real": ct, "long": ctypes.c_long}

        class Settings(ctypes.Structure):
            _fields_ = [(k, array(types[t], s)) for k, (t, s) in self.settings.items()]

        class State(ctypes.Structure):   # the leading fields; iw and w follow, opaque
            _fields_ = ([(k, array(ct, s)) for k, s in self.shapes.items()] + [("settings", Settings)]
                        + [(k, array(ctypes.c_long, s)) for k, s in self.counters.items()])

        fn = lambda name: getattr(self.lib, f"{self.prefix}_{name}")
        size = fn("state_size")
        size.restype = ctypes.c_size_t
        if size() < ctypes.sizeof(State):
            raise ValueError(f"{lib_path}: state layout does not match the filter")
        self._buf = ctypes.create_string_buffer(size())
        self._st = State.from_buffer(self._buf)
        self._init, self._step, self._std, self._reset = fn("init"), fn("step"), fn("std"), fn("reset")
        self._check = fn("settings_check")
        self._step.restype = self._reset.restype = self._check.restype = ctypes.c_int
        d = filt.aug.shapes
        self._u, self._y, self._out = (ct * d["nu"])(), (ct * d["ny"])(), (ct * self.n)()
        self._ct, self.P0 = ct, filt.aug.P0
        self.init()

    def init(self) -> None:
        self._init(ctypes.byref(self._st))

    def reset(self, z0=None, C0=None) -> None:
        """``<prefix>_reset``: restart from (z0, C0) (None: the declared value), settings kept.
        ValueError, the state unchanged, when the C refuses them."""
        arr = lambda a: None if a is None else (self._ct * (self.n * self.n if np.ndim(a) == 2 else self.n))(
            *np.ravel(a, order="F").tolist())
        sized = (z0 is None or np.size(z0) == self.n) and (C0 is None or np.size(C0) == self.n * self.n)
        code = self._reset(ctypes.byref(self._st), arr(z0), arr(C0)) if sized else -1
        if code:
            why = self.filt.start_refusal(z0, C0) or f"{self.prefix}_reset returned {code} (in {self.dtype.__name__})"
            raise ValueError(f"reset refused: {why}; the state is unchanged")

    def settings_check(self) -> str | None:
        """``<prefix>_settings_check``: None, or the name of the first setting that makes every
        step return :attr:`Status.BAD_SETTINGS`."""
        bad = self._check(ctypes.byref(self._st.settings))
        return list(self.settings)[bad - 1] if bad else None

    def configure(self, guard=None, **values) -> None:
        """Set fields of ``st.settings``: those of a :class:`~skigen.guard.Guard` and/or by name."""
        if guard is not None:
            values = {**{k: v for k, v in guard.asdict().items() if k in self.settings}, **values}
            values.setdefault("std_max", guard.std_max(self.P0))
        for name, value in values.items():
            if name not in self.settings:
                raise ValueError(f"no setting '{name}' (settings: {', '.join(self.settings)})")
            t, shape = self.settings[name]
            if shape:
                getattr(self._st.settings, name)[:_size(shape)] = np.broadcast_to(value, shape).ravel(order="F").tolist()
            else:
                setattr(self._st.settings, name, float(value) if t == "real" else int(value))

    def setting(self, name: str):
        t, shape = self.settings[name]
        v = getattr(self._st.settings, name)
        return np.array(v[:_size(shape)], self.dtype if t == "real" else int).reshape(shape, order="F") if shape \
            else (float(v) if t == "real" else int(v))

    def step(self, u, y) -> int:
        """One sample; returns the :class:`Status` code as an int."""
        u, y = np.ravel(u), np.ravel(y)
        if len(u) != len(self._u) or len(y) != len(self._y):
            raise ValueError(self.filt.size_refusal(u, y))
        self._u[:] = [float(v) for v in u]
        self._y[:] = [float(v) for v in y]
        return self._step(ctypes.byref(self._st), self._u, self._y)

    def std(self) -> np.ndarray:
        """Posterior standard deviations."""
        self._std(ctypes.byref(self._st), self._out)
        return np.array(self._out, dtype=self.dtype)

    def get(self, name: str):
        """A field of the state: real (an array of its shape, or a float) or a counter (int)."""
        if name in self.counters:
            shape, v = self.counters[name], getattr(self._st, name)
            return np.array(v[:_size(shape)], int) if shape else int(v)
        shape, v = self.shapes[name], getattr(self._st, name)
        if shape == ():
            return float(v)
        return np.array(v, dtype=self.dtype)[:_size(shape)].reshape(shape, order="F")

    def set(self, name: str, value) -> None:
        shape = self.shapes[name]
        if shape == ():
            setattr(self._st, name, float(value))
        else:
            getattr(self._st, name)[:_size(shape)] = np.broadcast_to(value, shape).ravel(order="F").tolist()

    def __getattr__(self, name):
        if name not in ("shapes", "counters") and (name in self.shapes or name in self.counters):
            return self.get(name)
        raise AttributeError(name)

    def snapshot(self) -> bytes:
        """The whole state, settings and counters, for :meth:`restore`."""
        return self._buf.raw

    def restore(self, snapshot: bytes) -> None:
        ctypes.memmove(self._buf, snapshot, len(snapshot))

    def run_many(self, inputs, outputs) -> dict[str, np.ndarray]:
        """Step over rows of ``inputs`` and ``outputs`` in one C call (libraries from :func:`load_c`):
        per sample the posterior mean ``z_post`` and ``std``, innovation ``e``, diagonal of ``Pyy``,
        ``nis``, ``loglik``, ARD variances ``s`` (SKI), the outputs ``used``, the status ``code`` and the
        states whose prior std was ``held`` at its bound."""
        count, d = len(inputs), {k: self.shapes[k] for k in ("e", "z_post")}
        u = np.ascontiguousarray(inputs, self.dtype).reshape(count, -1)
        y = np.ascontiguousarray(outputs, self.dtype).reshape(count, -1)
        nw = _size(self.shapes["s"]) if "s" in self.shapes else 0
        out = dict(z_post=(self.n,), std=(self.n,), e=d["e"], pyy=d["e"], nis=(), loglik=(), s=(nw,), used=d["e"])
        out = {k: np.empty((count, *shape), self.dtype) for k, shape in out.items()}
        out["code"], out["held"] = np.empty(count, np.intc), np.empty((count, self.n), np.intc)
        ptr = lambda a: a.ctypes.data_as(ctypes.c_void_p)
        fn = getattr(self.lib, f"{self.prefix}_run_many")
        fn.restype = None
        fn(ctypes.byref(self._st), ctypes.c_size_t(count), ptr(u), ptr(y),
           *(ptr(out[k]) for k in ("z_post", "std", "e", "pyy", "nis", "loglik", "s", "used", "code", "held")))
        out["held"] = out["held"] != 0
        return out

    def run(self, inputs, outputs) -> dict[str, np.ndarray]:
        """Step over rows of ``inputs`` (N×nu) and ``outputs`` (N×ny): posterior means, stds, codes."""
        inputs, outputs = np.asarray(inputs, float), np.asarray(outputs, float)
        N = len(inputs)
        z, sd, code = np.empty((N, self.n)), np.empty((N, self.n)), np.empty(N, int)
        for k in range(N):
            code[k] = self.step(inputs[k], outputs[k])
            z[k], sd[k] = self.get("z_post"), self.std()
        return dict(z_post=z, std=sd, code=code)


def _run_many_source(filt: DerivedFilter, out_dir, real: str, prefix: str) -> Path:
    """``<prefix>_run_many.c``: the batch loop :meth:`CFilter.run_many` calls."""
    d = filt.aug.shapes
    copy_s = (f"        for (i = 0; i < {d['nw']}; ++i) s[k * {d['nw']} + i] = st->s[i];"
              if filt.has_ard else "")
    text = string.Template((_HERE / "run_many.c.in").read_text()).substitute(
        prefix=prefix, real=real, N=d["n"], NU=d["nu"], NY=d["ny"], copy_s=copy_s)
    path = Path(out_dir) / f"{prefix}_run_many.c"
    path.write_text(text)
    return path


def load_c(filt: DerivedFilter, real: str = "double", prefix: str | None = None, cache_dir=None,
           cc: str | None = None, flags=DEFAULT_FLAGS, style: str = "auto") -> CFilter:
    """Emit, compile (cached) and load ``filt`` as a :class:`CFilter`."""
    with tempfile.TemporaryDirectory() as tmp:
        paths = emit_c(filt, tmp, real, prefix, style)
        paths.append(_run_many_source(filt, tmp, real, prefix or default_prefix(filt)))
        lib = compile_shared(paths, cc=cc, flags=flags, cache_dir=cache_dir)
    return CFilter(lib, filt, real, prefix)
