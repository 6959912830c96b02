"""Fused tick functions generated from the shared step functions' source (no algorithm twice).

The control core writes each algorithm once, as an ops-generic step function
(``td.py``, ``eso.py``, ``kalman.py``, ``law.py``), and :mod:`ladrc` composes them in a
*template* tick (plain Python calling those functions). Run as written, a tick makes
about six calls of ten arguments each, which dominates the 2 kHz scalar path. This
module turns a template into ONE function mechanically, at construction time:

1. structural names (``KALMAN``, ``EULER``, ``COMPENSATOR``, ``USE_TD`` and the peaking
   limits when switched off = ``None``) become literals and the ``if`` statements and
   conditional expressions they decide are folded away;
2. every statement ``targets = f(args)`` with ``f`` a registered step function is
   replaced by ``f``'s own body (read with :func:`inspect.getsource`, parsed with
   :mod:`ast`), its locals renamed uniquely, its arguments bound once (simple names and
   literals are substituted), its final ``return expr`` turned into ``targets = expr``;
   calls inside the inlined bodies (``_limit_ext``) are inlined the same way;
3. on the scalar path, ``ops.f(...)`` calls whose :data:`~ops.SCALAR` implementation is
   a single ``return expr`` (``clip``, ``where``) are replaced by that expression;
4. sub-expressions made only of per-instance constants (``h·R·R``, ``−k1``, ``h·β2``,
   ``−v_max``) are evaluated once when the function is built, not every tick;
5. on the batch path (``out_buffers=True``), arithmetic assigned to local names that do
   not leave the tick is evaluated into preallocated numpy buffers (``ufunc(..., out=)``)
   instead of fresh temporaries.

None of these steps changes an IEEE-754 operation or its operands' order: the same
``+ − × ÷`` run on the same values, so the fused tick equals the template bit for bit
(``tests/core/test_fuse.py`` checks every configuration in closed loop). The generated
source is compiled once per structure and cached; the constants are bound per instance
(a closure). ``fn.__fused_source__`` holds the generated text for inspection.
"""

from __future__ import annotations

import ast
import inspect
import itertools
import linecache
import textwrap
from typing import Any, Callable, Mapping

import numpy as np

from .ops import SCALAR

_counter = itertools.count()
_CACHE: dict[tuple, tuple[Callable, str]] = {}


# ----------------------------------------------------------------------------- parsing
def _function_ast(fn: Callable) -> ast.FunctionDef:
    """Parse ``fn``'s ``def`` (dedented; decorators and docstring dropped)."""
    tree = ast.parse(textwrap.dedent(inspect.getsource(fn)))
    node = tree.body[0]
    if not isinstance(node, ast.FunctionDef):
        raise ValueError(f'fuse: {fn.__qualname__} is not a plain function')
    node.decorator_list = []
    body = node.body
    if body and isinstance(body[0], ast.Expr) and isinstance(body[0].value, ast.Constant) \
            and isinstance(body[0].value.value, str):
        body = body[1:]
    node.body = body or [ast.Pass()]
    return node


def _assigned_names(stmts) -> set[str]:
    out = set()
    for st in stmts:
        for node in ast.walk(st):
            if isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
                out.add(node.id)
    return out


def _loaded_names(node) -> set[str]:
    return {n.id for n in ast.walk(node) if isinstance(n, ast.Name)
            and isinstance(n.ctx, ast.Load)}


class _Rename(ast.NodeTransformer):
    """Replace names by expressions (loads) or other names (stores)."""

    def __init__(self, mapping: Mapping[str, ast.AST]) -> None:
        self.mapping = mapping

    def visit_Name(self, node: ast.Name):
        rep = self.mapping.get(node.id)
        if rep is None:
            return node
        if isinstance(node.ctx, ast.Store):
            if not isinstance(rep, ast.Name):
                raise ValueError(f'fuse: cannot assign to substituted name {node.id!r}')
            return ast.copy_location(ast.Name(rep.id, ast.Store()), node)
        return ast.copy_location(_copy(rep), node)


def _copy(node):
    return ast.parse(ast.unparse(node), mode='eval').body if isinstance(node, ast.expr) \
        else node


# ----------------------------------------------------------------------------- folding
def _constant_value(node) -> tuple[bool, Any]:
    """Return ``(True, value)`` when ``node`` is built only from literals (foldable)."""
    for sub in ast.walk(node):
        if isinstance(sub, (ast.Name, ast.Call, ast.Attribute, ast.Subscript)):
            return False, None
    try:
        return True, eval(compile(ast.Expression(node), '<fold>', 'eval'),  # noqa: S307
                          {'__builtins__': {}})
    except Exception:  # noqa: BLE001 - not foldable, keep it
        return False, None


class _Fold(ast.NodeTransformer):
    """Substitute structural literals, then drop the branches they decide."""

    def __init__(self, literals: Mapping[str, Any]) -> None:
        self.literals = literals

    def visit_Name(self, node: ast.Name):
        if isinstance(node.ctx, ast.Load) and node.id in self.literals:
            return ast.copy_location(ast.Constant(self.literals[node.id]), node)
        return node

    def visit_If(self, node: ast.If):
        self.generic_visit(node)
        ok, val = _constant_value(node.test)
        if not ok:
            return node
        return (node.body if val else node.orelse) or [ast.Pass()]

    def visit_IfExp(self, node: ast.IfExp):
        self.generic_visit(node)
        ok, val = _constant_value(node.test)
        if not ok:
            return node
        return node.body if val else node.orelse

    def visit_BoolOp(self, node: ast.BoolOp):
        # `x is None or y is None` with one side folded to False: keep the other side
        self.generic_visit(node)
        keep = []
        for v in node.values:
            ok, val = _constant_value(v)
            if ok:
                if isinstance(node.op, ast.Or) and val:
                    return ast.copy_location(ast.Constant(True), node)
                if isinstance(node.op, ast.And) and not val:
                    return ast.copy_location(ast.Constant(False), node)
                continue
            keep.append(v)
        if not keep:
            return ast.copy_location(ast.Constant(isinstance(node.op, ast.And)), node)
        if len(keep) == 1:
            return keep[0]
        node.values = keep
        return node


def _fold(stmts, literals):
    mod = ast.Module(body=stmts, type_ignores=[])
    mod = _Fold(literals).visit(mod)
    return [s for s in mod.body if not isinstance(s, ast.Pass)] or [ast.Pass()]


# ----------------------------------------------------------------------------- inlining
class _Inliner:
    """Inline registered step functions (statement level) and scalar ops (expression level)."""

    def __init__(self, functions: Mapping[str, Callable], literals: Mapping[str, Any],
                 scalar_ops: bool, namespace: dict) -> None:
        self.functions = functions
        self.literals = literals
        self.scalar_ops = scalar_ops
        self.namespace = namespace
        self._defs: dict[str, ast.FunctionDef] = {}

    def _def(self, name: str) -> ast.FunctionDef:
        if name not in self._defs:
            self._defs[name] = _function_ast(self.functions[name])
        return self._defs[name]

    def _bind(self, fdef: ast.FunctionDef, call: ast.Call, fn: Callable, tag: str):
        """Map each parameter to an argument expression; return (prelude, mapping)."""
        params = [a.arg for a in fdef.args.args]
        defaults = fdef.args.defaults
        given: dict[str, ast.expr] = {}
        if any(isinstance(a, ast.Starred) for a in call.args) or any(
                k.arg is None for k in call.keywords):
            raise ValueError(f'fuse: call of {fdef.name} with *args/**kwargs cannot be inlined')
        for name, arg in zip(params, call.args, strict=False):
            given[name] = arg
        for kw in call.keywords:
            given[kw.arg] = kw.value
        for name, dflt in zip(params[len(params) - len(defaults):], defaults, strict=True):
            given.setdefault(name, dflt)
        missing = [p for p in params if p not in given]
        if missing:
            raise ValueError(f'fuse: call of {fdef.name} misses {missing}')
        body_assigned = _assigned_names(fdef.body)
        prelude, mapping = [], {}
        for name in params:
            arg = given[name]
            if name not in body_assigned and isinstance(arg, (ast.Name, ast.Constant)):
                mapping[name] = arg                      # substitute: evaluated once anyway
            else:
                new = f'{tag}{name}'
                prelude.append(ast.Assign([ast.Name(new, ast.Store())], _copy(arg)))
                mapping[name] = ast.Name(new, ast.Load())
        for name in body_assigned - set(params):
            mapping[name] = ast.Name(f'{tag}{name}', ast.Load())
        # free names of the inlined function (module globals it uses) must resolve here
        for name in _loaded_names(fdef) - set(mapping) - set(self.functions):
            if name in fn.__globals__:
                obj = fn.__globals__[name]
                if name in self.namespace and self.namespace[name] is not obj:
                    raise ValueError(f'fuse: global {name!r} of {fdef.name} clashes')
                self.namespace[name] = obj
        return prelude, mapping

    def _inline_call(self, targets, call: ast.Call):
        name = call.func.id
        fn = self.functions[name]
        fdef = self._def(name)
        tag = f'_{name.strip("_")}{next(_counter)}_'
        prelude, mapping = self._bind(fdef, call, fn, tag)
        body = [_Rename(mapping).visit(_copy_stmt(s)) for s in fdef.body]
        body = _fold(body, self.literals)
        if not body or not isinstance(body[-1], ast.Return) or any(
                isinstance(n, ast.Return) for s in body[:-1] for n in ast.walk(s)):
            raise ValueError(f'fuse: {name} must end in its only return statement')
        ret = body.pop().value
        out = prelude + body
        if targets is not None:
            out.append(ast.Assign(targets, ret))
        return self.statements(out)

    def statements(self, stmts):
        out = []
        for st in stmts:
            if isinstance(st, ast.Assign) and isinstance(st.value, ast.Call) and isinstance(
                    st.value.func, ast.Name) and st.value.func.id in self.functions:
                out += self._inline_call(st.targets, st.value)
                continue
            if isinstance(st, ast.If):
                st.body = self.statements(st.body)
                st.orelse = self.statements(st.orelse)
                out.append(st)
                continue
            for node in ast.walk(st):
                if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and \
                        node.func.id in self.functions:
                    raise ValueError(f'fuse: {node.func.id}(...) must be the whole right-hand'
                                     f' side of an assignment to be inlined: '
                                     f'{ast.unparse(st)}')
            if self.scalar_ops:
                pre = []
                st = _ScalarOps(pre).visit(st)
                out += pre
            out.append(st)
        return out


def _copy_stmt(st):
    return ast.parse(ast.unparse(st)).body[0]


class _ScalarOps(ast.NodeTransformer):
    """Replace ``ops.f(a, b)`` by the expression of ``SCALAR.f`` (args bound once)."""

    def __init__(self, prelude: list) -> None:
        self.prelude = prelude

    def visit_Call(self, node: ast.Call):
        self.generic_visit(node)
        f = node.func
        if not (isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name)
                and f.value.id == 'ops' and not node.keywords):
            return node
        impl = getattr(type(SCALAR), f.attr, None)
        if not inspect.isfunction(impl):
            return node                                  # a builtin (abs, min): keep the call
        fdef = _function_ast(impl)
        if len(fdef.body) != 1 or not isinstance(fdef.body[0], ast.Return):
            return node
        tag = f'_{f.attr}{next(_counter)}_'
        mapping = {}
        for p, arg in zip([a.arg for a in fdef.args.args], node.args, strict=False):
            if isinstance(arg, (ast.Name, ast.Constant)):
                mapping[p] = arg
            else:
                self.prelude.append(ast.Assign([ast.Name(tag + p, ast.Store())], arg))
                mapping[p] = ast.Name(tag + p, ast.Load())
        return _Rename(mapping).visit(_copy(fdef.body[0].value))


# ----------------------------------------------------------------------------- constants
def _hoist_constants(stmts, consts: set[str], factory: list, assigned_count=None) -> list:
    """Move constant statements and sub-expressions into the factory (evaluated once)."""
    if assigned_count is None:
        assigned_count = {}
        for st in stmts:
            for node in ast.walk(st):
                if isinstance(node, ast.Name) and isinstance(node.ctx, ast.Store):
                    assigned_count[node.id] = assigned_count.get(node.id, 0) + 1

    def is_const(node) -> bool:
        if isinstance(node, ast.Constant):
            return True
        if isinstance(node, ast.Name):
            return node.id in consts
        if isinstance(node, ast.BinOp):
            return is_const(node.left) and is_const(node.right)
        if isinstance(node, ast.UnaryOp):
            return is_const(node.operand)
        return False

    class Hoist(ast.NodeTransformer):
        def generic_visit(self, node):
            if isinstance(node, (ast.BinOp, ast.UnaryOp)) and is_const(node):
                ok, _ = _constant_value(node)
                if not ok:                              # involves per-instance constants
                    name = f'_k{next(_counter)}'
                    factory.append(ast.Assign([ast.Name(name, ast.Store())], node))
                    consts.add(name)
                    return ast.Name(name, ast.Load())
            return super().generic_visit(node)

    out = []
    for st in stmts:
        if isinstance(st, ast.If):
            st.test = Hoist().visit(st.test)
            st.body = _hoist_constants(st.body, consts, factory, assigned_count)
            st.orelse = _hoist_constants(st.orelse, consts, factory, assigned_count)
            out.append(st)
            continue
        if (isinstance(st, ast.Assign) and len(st.targets) == 1
                and isinstance(st.targets[0], ast.Name)
                and assigned_count.get(st.targets[0].id) == 1 and is_const(st.value)):
            factory.append(st)                          # e.g. a bound argument ``lo = -v_max``
            consts.add(st.targets[0].id)
            continue
        out.append(Hoist().visit(st))
    return out


# ----------------------------------------------------------------------------- buffers
_UFUNCS = {ast.Add: 'add', ast.Sub: 'subtract', ast.Mult: 'multiply', ast.Div: 'true_divide'}
# the ufunc numpy.clip itself ends in for float arrays (numpy/_core/_methods.py ``_clip``)
_CLIP_UFUNC = getattr(getattr(np, '_core', np).umath, 'clip', None)


def _top_names(v) -> list[str]:
    if isinstance(v, ast.Name):
        return [v.id]
    if isinstance(v, ast.Tuple):
        return [n for e in v.elts for n in _top_names(e)]
    if isinstance(v, ast.IfExp):
        return _top_names(v.body) + _top_names(v.orelse)
    return []


def _escaping(stmts) -> set[str]:
    """Local names whose value may outlive the tick or be aliased (these keep fresh arrays).

    A value escapes when stored to an attribute, returned, or bound to another name
    (``a = b``, tuples, conditional expressions): a scratch buffer would then be
    overwritten under the alias. Names only READ inside arithmetic do not escape.
    """
    esc: set[str] = set()
    changed = True
    while changed:
        changed = False
        for st in stmts:
            for node in ast.walk(st):
                vals = []
                if isinstance(node, ast.Return) and node.value is not None:
                    vals = [node.value]
                elif isinstance(node, ast.Assign):
                    if isinstance(node.value, (ast.Name, ast.Tuple, ast.IfExp)) or any(
                            not isinstance(t, ast.Name) or t.id in esc for t in node.targets):
                        vals = [node.value]
                for v in vals:
                    for name in _top_names(v):
                        if name not in esc:
                            esc.add(name)
                            changed = True
    return esc


def _split_tuples(stmts) -> list:
    """Split ``a, self.b = x, y`` into ``a = x; self.b = y`` when no right side reads a target."""
    out = []
    for st in stmts:
        if (isinstance(st, ast.Assign) and len(st.targets) == 1
                and isinstance(st.targets[0], ast.Tuple) and isinstance(st.value, ast.Tuple)
                and len(st.targets[0].elts) == len(st.value.elts)
                and all(isinstance(t, (ast.Name, ast.Attribute)) for t in st.targets[0].elts)):
            tnames = {t.id for t in st.targets[0].elts if isinstance(t, ast.Name)}
            reads_attr = any(isinstance(n, ast.Attribute) for v in st.value.elts
                             for n in ast.walk(v))
            if not reads_attr and not any(_loaded_names(v) & tnames for v in st.value.elts):
                out += [ast.Assign([t], v)
                        for t, v in zip(st.targets[0].elts, st.value.elts, strict=True)]
                continue
        out.append(st)
    return out


def _into_buffers(stmts, factory: list, n: int) -> list:
    """Evaluate arithmetic into preallocated arrays of ``n`` rows with ``ufunc(..., out=)``.

    Straight-line code only. A non-escaping local gets its own buffer (written by the
    statement's last ufunc); anonymous intermediates use a pool reused statement by
    statement; a value that escapes is still computed by a fresh ufunc call (its
    operands may come from buffers). The ufuncs are those the operators call.
    """
    stmts = _split_tuples(stmts)
    if any(isinstance(st, (ast.If, ast.For, ast.While)) for st in stmts):
        return stmts
    esc = _escaping(stmts)
    nbuf = itertools.count()
    out: list = []
    bufs: dict[str, str] = {}
    pool: list[str] = []

    def new_buf() -> str:
        name = f'_buf{next(nbuf)}'
        factory.append(ast.parse(f'{name} = _np_empty({n})').body[0])
        return name

    def call(fn: str, args: list, out_name: str | None) -> ast.expr:
        kw = [] if out_name is None else [ast.keyword('out', ast.Name(out_name, ast.Load()))]
        return ast.Call(ast.Name(fn, ast.Load()), args, kw)

    def emit_probe(node) -> str | None:
        if isinstance(node, ast.BinOp) and type(node.op) in _UFUNCS:
            return 'ufunc'
        if isinstance(node, ast.UnaryOp) and isinstance(node.op, ast.USub):
            return 'ufunc'
        if (_CLIP_UFUNC is not None and isinstance(node, ast.Call)
                and isinstance(node.func, ast.Attribute) and node.func.attr == 'clip'
                and isinstance(node.func.value, ast.Name) and node.func.value.id == 'ops'
                and len(node.args) == 3 and not node.keywords):
            return 'clip'
        return None

    def emit(node, target: str | None, used: list) -> ast.expr:
        """Return an expression for ``node``; buffered sub-results are emitted first."""
        kind = emit_probe(node)
        if kind is None:
            return node
        if kind == 'clip':
            fn, args = '_np_clip', list(node.args)
        elif isinstance(node, ast.BinOp):
            fn, args = '_np_' + _UFUNCS[type(node.op)], [node.left, node.right]
        else:
            fn, args = '_np_negative', [node.operand]
        args = [emit(a, None, used) for a in args]
        if target == '':                                # the escaping top: a fresh result
            return call(fn, args, None)
        if target is None:
            if len(used) == len(pool):
                pool.append(new_buf())
            target = pool[len(used)]
            used.append(target)
        out.append(ast.Expr(call(fn, args, target)))
        return ast.Name(target, ast.Load())

    for st in stmts:
        rename = _Rename({k: ast.Name(v, ast.Load()) for k, v in bufs.items()})
        if isinstance(st, ast.Assign):
            st.value = rename.visit(st.value)
        else:
            st = rename.visit(st)
        used: list[str] = []
        if (isinstance(st, ast.Assign) and len(st.targets) == 1
                and isinstance(st.targets[0], ast.Name) and st.targets[0].id not in esc
                and isinstance(emit_probe(st.value), str)):
            name = st.targets[0].id
            if name not in bufs:
                bufs[name] = new_buf()
            emit(st.value, bufs[name], used)
            continue
        for name in _assigned_names([st]):
            bufs.pop(name, None)                        # rebound to a fresh value
        if isinstance(st, (ast.Assign, ast.Return)) and st.value is not None:
            if isinstance(st.value, ast.Tuple):
                st.value.elts = [emit(e, '', used) for e in st.value.elts]
            else:
                st.value = emit(st.value, '', used)
        out.append(st)
    return out


# ----------------------------------------------------------------------------- build
def build(template: Callable, functions: Mapping[str, Callable], literals: Mapping[str, Any],
          consts: Mapping[str, Any], ops, *, fused: bool = True, scalar_ops: bool = False,
          out_buffers: int | None = None) -> Callable:
    """Return ``template`` as a function with ``consts`` and ``ops`` bound (a closure).

    ``fused=False`` compiles the template as written (the plain composition, the
    reference of the equivalence tests); ``fused=True`` applies the steps of the module
    doc. ``literals`` are the structural values (folded), ``consts`` the numbers (bound
    per call of the returned factory; scalars or numpy arrays). ``out_buffers`` = N
    evaluates non-escaping arithmetic into preallocated arrays of N rows.
    """
    names = sorted(consts)
    key = (template.__module__, template.__qualname__, tuple(sorted(literals.items())),
           tuple(names), fused, scalar_ops, out_buffers)
    if key not in _CACHE:
        _CACHE[key] = _generate(template, functions, literals, names, fused, scalar_ops,
                                out_buffers)
    factory, source = _CACHE[key]
    fn = factory(ops, **consts)
    fn.__fused_source__ = source
    return fn


def _generate(template, functions, literals, names, fused, scalar_ops, out_buffers):
    fdef = _function_ast(template)
    namespace: dict[str, Any] = {k: v for k, v in template.__globals__.items()
                                 if k in _loaded_names(fdef)}
    namespace['_np_empty'] = np.empty
    namespace['_np_clip'] = _CLIP_UFUNC
    for op in (*_UFUNCS.values(), 'negative'):
        namespace['_np_' + op] = getattr(np, op)
    factory_body: list = []
    if fused:
        clash = _assigned_names(fdef.body) & (set(names) | set(literals))
        if clash:
            raise ValueError(f'fuse: the template assigns constant names {sorted(clash)}')
        body = _fold(fdef.body, literals)
        body = _Inliner(functions, literals, scalar_ops, namespace).statements(body)
        body = _fold(body, literals)
        body = _hoist_constants(body, set(names), factory_body)
        if out_buffers:
            body = _into_buffers(body, factory_body, out_buffers)
        fdef.body = body
    else:
        namespace.update(functions)
        factory_body = [ast.Assign([ast.Name(k, ast.Store())], ast.Constant(v))
                        for k, v in sorted(literals.items())]
    factory = ast.FunctionDef(
        name='_factory',
        args=ast.arguments(posonlyargs=[], args=[ast.arg('ops')], vararg=None,
                           kwonlyargs=[ast.arg(n) for n in names],
                           kw_defaults=[None] * len(names), kwarg=None, defaults=[]),
        body=[*factory_body, fdef, ast.Return(ast.Name(fdef.name, ast.Load()))],
        decorator_list=[], returns=None, type_comment=None)
    module = ast.fix_missing_locations(ast.Module(body=[factory], type_ignores=[]))
    source = ast.unparse(module) + '\n'
    filename = f'<fused {template.__qualname__} #{next(_counter)}>'
    linecache.cache[filename] = (len(source), None, source.splitlines(True), filename)
    exec(compile(source, filename, 'exec'), namespace)  # noqa: S102 - our own generated code
    return namespace['_factory'], source
