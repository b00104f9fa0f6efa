"""Progress in a log: plain lines every tenth of the work, no carriage returns, when stderr is no terminal."""

import io

from va_plugin.utils.progress import PlainProgress, progress_bar


def test_plain_lines_every_tenth_and_at_the_end():
    out = io.StringIO()
    bar = PlainProgress(total=200, desc="neus", file=out)
    for step in range(200):
        bar.update(1)
        bar.set_postfix({"loss": f"{1.0 / (step + 1):.3g}"})
    bar.close()
    lines = out.getvalue().splitlines()
    assert "\r" not in out.getvalue() and len(lines) == 10
    assert lines[0].startswith("neus: 20/200 (10%), loss 0.05") and "s left" in lines[0]
    assert lines[-1] == "neus: 200/200 (100%), loss 0.005"


def test_iterating_and_resuming_part_way():
    out = io.StringIO()
    assert list(PlainProgress(range(5), desc="views", file=out)) == [0, 1, 2, 3, 4]
    assert out.getvalue().splitlines()[-1] == "views: 5/5 (100%)"
    out = io.StringIO()
    bar = PlainProgress(total=100, initial=95, desc="resumed", file=out)
    for _ in range(5):
        bar.update(1)
    bar.close()
    assert out.getvalue().splitlines() == ["resumed: 100/100 (100%)"]


def test_disabled_prints_nothing_and_a_log_gets_plain_progress(capsys):
    bar = PlainProgress(total=10, disable=True, file=io.StringIO())
    bar.update(10)
    bar.close()
    assert isinstance(progress_bar(range(3), desc="x"), PlainProgress)  # pytest's stderr is no terminal
    for _ in progress_bar(range(3), desc="turntable"):
        pass
    err = capsys.readouterr().err
    assert "\r" not in err and err.splitlines()[-1] == "turntable: 3/3 (100%)" and len(err.splitlines()) == 3
