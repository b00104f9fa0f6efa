import contextlib
import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

from va_plugin.utils.interrupts import interrupt_deferred, signals_held


@pytest.fixture(autouse=True)
def python_sigint_handler():
    """These tests need Python's own SIGINT handler; a run started in the background (``make test &``)
    inherits SIGINT ignored, where interrupt_deferred rightly does nothing."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


def _swallowing_code():
    """What trimesh does around its optional imports."""
    with contextlib.suppress(BaseException):
        time.sleep(0.05)


def test_a_ctrl_c_inside_the_block_is_raised_after_it():
    with pytest.raises(KeyboardInterrupt), interrupt_deferred():
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


def test_sigterm_inside_a_command_is_taken_like_ctrl_c():
    """friendly_errors runs a command with SIGTERM raising KeyboardInterrupt: it ends as 'interrupted' with
    exit status 130 (after the command's own interrupt handling), and SIGTERM's default is back afterwards."""
    from va_plugin.cli.common import EXIT_INTERRUPTED, friendly_errors

    reached = []

    @friendly_errors
    def command() -> int:
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(5)
        except KeyboardInterrupt:
            reached.append("saved")
            raise
        return 0

    assert command() == EXIT_INTERRUPTED and reached == ["saved"]
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL


def test_sigterm_stops_a_parallel_benchmark_and_its_workers(tmp_path):
    """``kill`` on run_backbone --jobs 2 interrupts its worker processes too (they used to run on, orphaned,
    until their rows ended) and the command exits 130."""
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    command = [sys.executable, os.path.join(root, "benchmarks", "run_backbone.py"), "--preset", "smoke",
               "--jobs", "2", "--steps", "100000", "--out", str(tmp_path / "out")]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                               start_new_session=True)
    try:
        children = []
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and len(children) < 2:  # both workers started and busy
            time.sleep(2)
            listed = subprocess.run(["pgrep", "-P", str(process.pid)], capture_output=True, text=True).stdout.split()
            children = [int(pid) for pid in listed if _cpu_seconds(int(pid)) > 3.0]
        assert len(children) == 2, "the workers did not start"
        process.send_signal(signal.SIGTERM)
        output, _ = process.communicate(timeout=240)
        assert process.returncode == 130, output
        assert not [pid for pid in children if _alive(pid)], output
    finally:  # whatever happened, nothing of it keeps running
        with contextlib.suppress(ProcessLookupError):
            os.killpg(process.pid, signal.SIGKILL)
        process.wait()


def _cpu_seconds(pid: int) -> float:
    try:
        with open(f"/proc/{pid}/stat") as stat:
            fields = stat.read().rsplit(")", 1)[1].split()
    except OSError:
        return 0.0
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as stat:
            state = stat.read().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


def test_inside_signals_as_requests_the_first_signal_is_a_request_and_the_second_interrupts():
    from va_plugin.utils.interrupts import signals_as_requests

    asked = []
    with pytest.raises(KeyboardInterrupt), signals_as_requests(asked.append):
        os.kill(os.getpid(), signal.SIGTERM)
        _swallowing_code()  # the handler runs here; nothing is raised
        assert asked == [signal.SIGTERM]
        os.kill(os.getpid(), signal.SIGINT)  # the second: Python's Ctrl-C, at once
        time.sleep(5)
    assert asked == [signal.SIGTERM]
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL


def test_signals_as_requests_leaves_an_ignored_signal_ignored():
    from va_plugin.utils.interrupts import signals_as_requests

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    asked = []
    with signals_as_requests(asked.append):
        os.kill(os.getpid(), signal.SIGINT)
        _swallowing_code()
    assert asked == [] and signal.getsignal(signal.SIGINT) is signal.SIG_IGN


def test_the_signal_plan_of_the_test_hook():
    from va_plugin.utils.interrupts import signal_plan

    assert signal_plan("12:INT, 20:sigterm@start,3:KILL@end") == {
        (12, "mid"): signal.SIGINT, (20, "start"): signal.SIGTERM, (3, "end"): signal.SIGKILL}
    assert signal_plan(None) == {} and signal_plan("") == {}
    for bad in ("x:INT", "3:NOPE", "3:INT@later", "3"):
        with pytest.raises(ValueError, match="STEP:SIGNAL"):
            signal_plan(bad)


_ORPHAN = textwrap.dedent("""
    import os, signal, sys, time
    from va_plugin.utils.interrupts import interrupt_when_orphaned
    marker, ignore = sys.argv[2], sys.argv[3] == "ignore"
    def interrupted(signum, frame):
        open(marker, "w").write("interrupted")
        os._exit(0)
    signal.signal(signal.SIGINT, signal.SIG_IGN if ignore else interrupted)
    interrupt_when_orphaned(int(sys.argv[1]), poll_seconds=0.05, grace_seconds=0.5)
    open(marker + ".ready", "w").write("")
    time.sleep(60)
""")

_PARENT = textwrap.dedent("""
    import os, subprocess, sys, time
    child = subprocess.Popen([sys.executable, "-c", sys.argv[1], str(os.getpid()), sys.argv[2], sys.argv[3]])
    print(child.pid, flush=True)
    while not os.path.exists(sys.argv[2] + ".ready"):
        time.sleep(0.05)
    os._exit(0)  # gone without a word to the child
""")


@pytest.mark.parametrize("child_ignores_sigint", [False, True])
def test_a_worker_whose_main_process_died_is_interrupted_then_ended(tmp_path, child_ignores_sigint):
    """interrupt_when_orphaned: the worker gets the SIGINT a Ctrl-C would send once its main process is gone,
    and ends after the grace time when it does not stop by itself."""
    marker = tmp_path / "marker"
    mode = "ignore" if child_ignores_sigint else "handle"
    parent = subprocess.run([sys.executable, "-c", _PARENT, _ORPHAN, str(marker), mode], capture_output=True,
                            text=True, timeout=60, check=True)
    child = int(parent.stdout.split()[0])
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline and _alive(child):
        time.sleep(0.05)
    assert not _alive(child)
    assert marker.exists() != child_ignores_sigint


def test_signals_held_wait_for_the_block_then_go_to_the_handler_before_it():
    with pytest.raises(KeyboardInterrupt), signals_held():
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)
        reached_the_end = True
    assert reached_the_end and signal.getsignal(signal.SIGINT) is signal.default_int_handler
    with signals_held(hand_on=False):  # the caller stops anyway: the signal is dropped
        os.kill(os.getpid(), signal.SIGINT)
        time.sleep(0.05)
    assert signal.getsignal(signal.SIGINT) is signal.default_int_handler
