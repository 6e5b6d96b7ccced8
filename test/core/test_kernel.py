"""The compiled kernel as a whole: the same numbers on every run, and numba's cache outside the
package, keyed on every compiled source (the algorithms themselves are held to their papers in
their own tests, to the golden traces in test_golden.py, and block by block against the loops
in test_batch.py)."""

from __future__ import annotations

import io
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from turning_force.core import kernel
from turning_force.core.experiment import load_experiment
from turning_force.core.kernel.simulate import simulate

EXPERIMENTS = Path(__file__).resolve().parents[2] / 'config' / 'experiments'
FILES = sorted(EXPERIMENTS.glob('*.yaml'))
FIG8 = EXPERIMENTS / 'park1998_fig8.yaml'


def test_compiled_runs_are_deterministic():
    e = load_experiment(FIG8).with_sets(['lathe_sim.force_noise_fraction=0.02'])
    first, second = simulate(e), simulate(e)
    for name, values in first.trace.items():
        np.testing.assert_array_equal(values, second.trace[name], err_msg=name)


def test_a_plant_run_again_under_another_law_cuts_through_the_same_noise_as_drawn_afresh():
    # The last run's noise serves the next run of the same plant (the verification runs each
    # plant under a dozen candidates in turn): the same numbers as a draw of its own.
    noisy = load_experiment(FIG8).with_sets(['lathe_sim.force_noise_fraction=0.02',
                                             'experiment.duration_s=3.0'])
    other_plant = noisy.with_sets(['lathe_sim.seed=99'])
    other_law = noisy.with_sets(['force_controller.controller=pi'])
    simulate(other_plant)
    simulate(noisy)                       # drawn, and kept
    reused = simulate(other_law)          # the same plant: its noise taken again
    simulate(other_plant)                 # another plant: drawn, and kept instead
    drawn = simulate(other_law)           # drawn afresh
    for name, values in drawn.trace.items():
        np.testing.assert_array_equal(values, reused.trace[name], err_msg=name)
    assert not np.array_equal(drawn.trace['force_n'], simulate(noisy).trace['force_n'])


def test_every_compiled_source_keys_the_cache(monkeypatch):
    # numba checks only a function's own file when it reads its cache: the folder's name
    # changes with any source of the core, so that a change never meets old machine code.
    from turning_force.core import codecache

    before = kernel.cache_dir()
    original = Path.read_bytes

    def edited(path: Path) -> bytes:
        data = original(path)
        return data + b'# edited' if path.name == 'gate.py' else data

    monkeypatch.setattr(Path, 'read_bytes', edited)
    codecache.source_hash.cache_clear()
    try:
        assert kernel.cache_dir() != before
        assert kernel.cache_dir().parent == before.parent
    finally:
        monkeypatch.undo()
        codecache.source_hash.cache_clear()
    assert kernel.cache_dir() == before
    # So does a law another package installs (its name, and its module's source).
    monkeypatch.setattr(codecache, 'installed_laws', lambda: (('theirs', 'json', 'their-dist'),))
    codecache.source_hash.cache_clear()
    try:
        assert kernel.cache_dir() != before
    finally:
        monkeypatch.undo()
        codecache.source_hash.cache_clear()
    assert kernel.cache_dir() == before


def test_a_loaded_kernel_leaves_the_cache_warm_outside_the_package(monkeypatch, tmp_path):
    # The nodes decide between loading the kernel and staying in Python by this, without
    # importing numba: the cache's folder is keyed on the sources' hash, and so is the stamp.
    # numba's files go to the user's cache, never into the package (a read-only install).
    kernel.load()
    assert kernel.cache_is_warm()
    package = Path(kernel.__file__).parents[2]
    assert not [*package.rglob('*.nbi'), *package.rglob('*.nbc')]
    assert package not in kernel.cache_dir().parents
    monkeypatch.setenv('NUMBA_CACHE_DIR', str(tmp_path))
    assert kernel.cache_dir().parent == tmp_path
    assert not kernel.cache_is_warm()


@pytest.mark.slow
def test_a_first_compilation_says_what_it_does(tmp_path):
    # A fresh cache: the load compiles numba's cache, then the module compiled ahead of time,
    # says so on stderr with where and how long, and leaves both for the next process, which
    # says nothing and loads the module without numba.
    env = {**os.environ, 'NUMBA_CACHE_DIR': str(tmp_path)}
    code = ('import sys; from turning_force.core import kernel; kernel.load(); '
            'print(kernel.cache_is_warm(), kernel.mode(), "numba" in sys.modules)')
    first = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True,
                           text=True, timeout=600, check=True)
    assert first.stdout.strip() == 'True just in time True'
    assert re.fullmatch(r'turning_force: compiling the kernel into \S+ \(once per install and '
                        r'version: 15 to 60 s\)\nturning_force: kernel compiled in \d+ s\n'
                        r'turning_force: compiling the kernel ahead of time into \S+\.so \(once '
                        r'per install and version: 30 to 90 s\)\nturning_force: kernel compiled '
                        r'ahead of time in \d+ s\n', first.stderr), first.stderr
    second = subprocess.run([sys.executable, '-c', code], env=env, capture_output=True,
                            text=True, timeout=600, check=True)
    assert (second.stdout.strip(), second.stderr) == ('True ahead of time False', '')


def test_the_kernel_compiled_ahead_of_time_runs_without_numba():
    # make setup (kernel.prepare) compiles it for this CPU (NUMBA_CPU_NAME where given); a run
    # then imports no numba at all, and its numbers are those of numba's dispatchers, bit for
    # bit: the module is compiled from the same functions (their optimised code, linked) for
    # the same CPU, and no floating-point rewriting (fast-math, contraction) is allowed in
    # either.
    subprocess.run([sys.executable, '-c', 'from turning_force.core import kernel; '
                    'kernel.prepare()'], check=True, timeout=600)
    code = ('import sys, numpy as np; from turning_force.core import kernel; '
            'from turning_force.core.experiment import load_experiment; '
            'from turning_force.core.kernel.simulate import simulate; '
            f'r = simulate(load_experiment({str(FIG8)!r})); '
            'np.save(sys.stdout.buffer, np.stack(list(r.trace.values()))); '
            'print(kernel.mode(), "numba" in sys.modules, file=sys.stderr)')
    runs = {}
    for ahead in ('1', '0'):
        run = subprocess.run([sys.executable, '-c', code], capture_output=True, timeout=600,
                             check=True, env={**os.environ, 'TURNING_FORCE_AOT': ahead})
        runs[ahead] = np.load(io.BytesIO(run.stdout))
        assert run.stderr.decode().strip() == {'1': 'ahead of time False',
                                                '0': 'just in time True'}[ahead]
    np.testing.assert_array_equal(runs['1'], runs['0'])


def test_an_entry_point_takes_its_signature_and_compiles_nothing_else():
    # Entry points are compiled for their signature and take nothing else: a call with other
    # types (a float32 array, a strided one) is a TypeError, not seconds of compiling
    # (numba's dispatcher is closed) nor memory read as another type (the module compiled
    # ahead of time reads what the signature says).
    from turning_force.core.control import ControllerSettings, law, make_controller, update

    controller = make_controller(ControllerSettings())
    cp, cs, levels = controller.arrays
    out = np.zeros(law.OUT_SIZE)   # numba checks no bounds: a shorter one is written past
    update.control_step(cp, cs, levels, 500.0, 0.0, out)
    assert np.isfinite(out[law.OUT_PCT])
    for bad in (cp.astype(np.float32), np.repeat(cp, 2)[::2]):
        with pytest.raises(TypeError):
            update.control_step(bad, cs, levels, 500.0, 0.0, out)
    with pytest.raises(TypeError):
        update.control_step(cp, cs, levels, 500.0, 0.0)
    if kernel.mode() == 'just in time':
        assert len(update.control_step.signatures) == 1


def test_the_compiled_code_calls_no_blas():
    # compiled._target_without_blas skips numba's check for a BLAS (an import of scipy.linalg,
    # 0.14 s of a short run's start-up) where only our laws are installed: that holds only as
    # long as none of our compiled functions calls one (np.dot, @, np.linalg, np.vdot, ...).
    import ast
    import inspect

    from turning_force.core import compiled

    kernel.load()
    blas = {'dot', 'vdot', 'inner', 'outer', 'matmul', 'linalg', 'kron', 'trace', 'cov'}
    users, read = [], set()
    for name, module in list(sys.modules.items()):
        if not name.startswith('turning_force') or module is None:
            continue
        for value in list(vars(module).values()):
            function = getattr(value, 'py_func', None)
            if function is None or function.__module__ != name:
                continue
            read.add(f'{name}.{function.__name__}')
            tree = ast.parse(inspect.getsource(function).lstrip())
            for node in ast.walk(tree):
                if (isinstance(node, ast.BinOp) and isinstance(node.op, ast.MatMult)) or (
                        isinstance(node, ast.Attribute) and node.attr in blas):
                    users.append(f'{name}.{function.__name__}')
    assert compiled.active() and not users
    # Every stage's functions were read: the plant's, the estimator's, each law's, the gate's.
    assert {'turning_force.core.plant.lathe.plant_step', 'turning_force.core.pmc.gate._judge',
            'turning_force.core.estimation.estimator.estimator_update',
            'turning_force.core.control.laws.smc.step', 'turning_force.core.control.rls.update',
            'turning_force.core.kernel.loops.chain_step'} <= read


def test_a_warm_start_does_not_import_scipy_linalg(fig8):
    # With a warm cache and only our laws, numba's BLAS check (an import of scipy.linalg) is
    # skipped; the run is the same run.
    import subprocess

    kernel.load()
    code = ('import sys; from turning_force.core.experiment import load_experiment; '
            'from turning_force.core.kernel.simulate import simulate; '
            f'r = simulate(load_experiment({str(fig8)!r})); '
            "print('scipy.linalg' in sys.modules, r.metrics['steady_mean_abs_error_n'])")
    out = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=300, check=True).stdout.split()
    expected = simulate(load_experiment(fig8)).metrics['steady_mean_abs_error_n']
    assert out == ['False', repr(expected)]


def test_a_warm_start_makes_only_the_entry_points_dispatchers():
    # With a warm cache the entry points' machine code is read whole: the other compiled
    # functions wait, and a call from Python makes them dispatchers, in every module that holds
    # one by name (control.update imports law.clip).
    import json
    import subprocess

    kernel.load()
    code = '\n'.join([
        'import json, numpy as np',
        'from turning_force.core import kernel',
        'kernel.load()',
        'from turning_force.core.control import law, rls, update',
        'before = [type(f).__name__ for f in (rls.update, law.clip, update.clip)]',
        'p = np.array(rls.params([0.0] * 4, 1e6)); s = np.zeros(rls.STATE)',
        'rls.restart(p, s, 0, 0); rls.update(p, s, 0, 0, 1.0, 2.0, 3.0, 4.0, 5.0)',
        'print(json.dumps([before, type(update.clip).__name__, update.clip is law.clip,',
        '                  s[rls.S_THETA:rls.S_THETA + 4].tolist()]))'])
    before, after, same, theta = json.loads(subprocess.run(
        [sys.executable, '-c', code], capture_output=True, text=True, timeout=300,
        check=True).stdout)
    assert before == ['_Deferred'] * 3 and after == 'CPUDispatcher' and same
    # The same update as compiled from the start: theta moves along x (P0 = 1e6 I, one sample).
    x = np.array([1.0, 2.0, 3.0, 4.0])
    np.testing.assert_allclose(theta, x * 5.0 / (1e-6 + x @ x), rtol=1e-5)


def test_an_entry_point_the_cache_misses_compiles_with_its_callees(tmp_path):
    # A cache stamped warm whose machine code for an entry point is not there (CI saw it: two
    # checkouts shared a stamp): activation defers the other functions, so the entry point's
    # compilation first meets deferred callees; it makes their dispatchers and compiles. The
    # entry point: the controller's spindle speed, whose callee (law.spindle_speed) sets the
    # feed rate of the 100 % override, feed per rev x rpm, from the live speed or, where that
    # is NaN, the parameter (a small entry point: a large one compiles for 20 s here).
    import subprocess

    code = '\n'.join([
        'import numpy as np',
        'from turning_force.core import codecache, kernel',
        'codecache.cache_dir().mkdir(parents=True)',
        '(codecache.cache_dir() / codecache.STAMP).write_text(codecache.source_hash())',
        'kernel.load()',
        'from turning_force.core.control import law',
        'cp = np.zeros(law.C_LAW)',
        'cp[law.C_FEED_REV], cp[law.C_RPM_SET] = 0.25, 800.0',
        'law.set_spindle_speed(cp, 1000.0)',
        'live = cp[law.C_FEED_RATE]',
        "law.set_spindle_speed(cp, float('nan'))",
        'print(type(law.spindle_speed).__name__, live, cp[law.C_FEED_RATE], cp[law.C_RPM])'])
    env = {**os.environ, 'NUMBA_CACHE_DIR': str(tmp_path)}
    run = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                         timeout=600, check=False, env=env)
    assert run.returncode == 0, run.stderr[-2000:]
    # compiled (numba's dispatcher, not a deferred stand-in), and right both ways
    assert run.stdout.split() == ['CPUDispatcher', '250.0', '200.0', '800.0'], run.stdout


def test_the_ahead_of_time_module_is_named_for_the_processor_it_was_compiled_for(
        monkeypatch: pytest.MonkeyPatch) -> None:
    # A cache folder on a network home is shared by machines: a module compiled for 'host' on
    # one processor (AVX-512, say) must not be the module another processor loads.
    from turning_force.core import aot

    monkeypatch.delenv('NUMBA_CPU_NAME', raising=False)
    monkeypatch.setattr(aot, '_host_features', lambda: 'model name: A|flags: avx512f')
    first = aot.module_name()
    monkeypatch.setattr(aot, '_host_features', lambda: 'model name: B|flags: avx2')
    assert aot.module_name() != first
    # a named CPU is the same on every processor: its name says all
    monkeypatch.setenv('NUMBA_CPU_NAME', 'generic')
    generic = aot.module_name()
    monkeypatch.setattr(aot, '_host_features', lambda: 'model name: A|flags: avx512f')
    assert aot.module_name() == generic
