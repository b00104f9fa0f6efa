import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from va_plugin.utils.interrupts import interrupt_deferred


@pytest.fixture(autouse=True)
def python_sigint_handler():
    """These tests need Python's own SIGINT handler; a run started in the background (``make test &``)
    inherits SIGINT ignored, where interrupt_deferred rightly does nothing."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def _swallowing_code():
    """What trimesh does around its optional imports."""
    try:
        time.sleep(0.05)
    except BaseException:
        pass


def test_a_ctrl_c_inside_the_block_is_raised_after_it():
    with pytest.raises(KeyboardInterrupt):
        with interrupt_deferred():
            os.kill(os.getpid(), signal.SIGINT)
            _swallowing_code()
            reached_the_end = True
    assert reached_the_end
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_without_a_ctrl_c_the_block_runs_as_usual():
    with interrupt_deferred():
        _swallowing_code()
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler


def test_a_ctrl_c_while_trimesh_imports_its_optional_parts_interrupts_the_import_of_va_plugin():
    """Deterministic: an import hook sends SIGINT exactly when trimesh imports networkx inside its
    ``except BaseException``; without the deferral trimesh swallows it and the program goes on."""
    script = textwrap.dedent("""
        import os, signal, sys
        signal.signal(signal.SIGINT, signal.default_int_handler)

        class Interrupter:
            def find_spec(self, name, path=None, target=None):
                if name == "networkx":
                    os.kill(os.getpid(), signal.SIGINT)
                return None

        sys.meta_path.insert(0, Interrupter())
        try:
            import va_plugin
        except KeyboardInterrupt:
            print("interrupted")
        else:
            print("swallowed")
    """)
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert done.stdout.strip() == "interrupted", done.stdout + done.stderr
