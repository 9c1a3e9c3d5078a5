"""What the two command-line programs (``sympredict``, ``sympredict-paper``) are checked for alike."""

import pytest


def assert_refused_in_one_line(main, argv, capsys):
    """``main(argv)`` is refused by its parser: exit status 2 and one line on stderr naming the argument."""
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 2
    err = capsys.readouterr().err
    assert len(err.strip().splitlines()) == 1 and "error: argument" in err, err
