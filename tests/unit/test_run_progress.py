"""`vrsim run`'s progress with no terminal attached (a log file, a CI job): a plain line now and then,
never a carriage-return bar; nothing with --quiet."""

import time

from vrsim.services.cli.run import Progress


def test_without_a_terminal_a_plain_line_every_few_seconds(capsys, monkeypatch):
    monkeypatch.setattr(Progress, "LOG_EVERY_S", 0.0)
    bar = Progress("vrsim run huge", enabled=True)
    bar.start -= 2.0  # past the first second
    bar(250, 1000)
    time.sleep(0.01)
    bar(500, 1000)
    bar.close()
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 2 and "\r" not in "".join(lines)
    assert lines[0].startswith("vrsim run huge: control loop  25.0 % after 2 s")
    assert " 50.0 %" in lines[1]


def test_quiet_and_the_first_second_say_nothing(capsys):
    Progress("vrsim run q", enabled=False)(1, 2)
    Progress("vrsim run q", enabled=True)(1, 2)
    assert capsys.readouterr().err == ""
