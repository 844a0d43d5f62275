"""Progress on stderr: a tqdm bar on a terminal; plain lines, or nothing, elsewhere.

One :class:`Progress` serves the two bars warpe-cl shows:

- the rays of one scenario (:func:`warpe_cl.api.simulate_point`): on a terminal only, shown
  once a run has taken 2 s, removed when it ends;
- the scenarios of a sweep (:func:`warpe_cl.sweep.run_sweep`): on a terminal a bar with each
  failure printed above it; elsewhere one plain line per scenario.

tqdm is imported only when a bar is shown.
"""
from __future__ import annotations

import sys


class Progress:
    """A tqdm bar over ``total`` units on stderr, or the plain lines of :meth:`advance`.

    Parameters
    ----------
    total : int
        Units to go (rays, scenarios); 0 shows no bar.
    show : bool or None
        None: a bar where stderr is a terminal; a true value: a bar anywhere; a false one: none.
    quiet : bool
        Print no plain line but errors (:meth:`write`, :meth:`advance`).
    **bar
        tqdm's options for the bar's look: ``unit``, ``unit_scale``, ``desc``, ``delay`` (s
        before the bar appears), ``leave``, ``dynamic_ncols``.

    Examples
    --------
    >>> bar = Progress(3, show=False)
    >>> bar.advance("first done")
    [1/3] first done
    >>> bar.close()
    """

    def __init__(self, total: int, show=None, *, quiet: bool = False, **bar):
        self.total, self.quiet = total, quiet
        self.count = 0              # units done (update_to) or steps taken (advance)
        self.bar = None
        if show is None:
            show = sys.stderr.isatty()
        if show and total:
            from tqdm.auto import tqdm
            self.bar = tqdm(total=total, file=sys.stderr, **bar)

    def update_to(self, done: int) -> None:
        """Move the bar to ``done`` units (the engines' ``progress`` callback)."""
        if self.bar is not None:
            self.bar.update(done - self.count)
        self.count = done

    def write(self, text: str, error: bool = False) -> None:
        """A line above the bar, or on its own: stdout, or stderr for an error."""
        if self.bar is not None:
            self.bar.write(text, file=sys.stderr if error else sys.stdout)
        elif error or not self.quiet:
            print(text, file=sys.stderr if error else sys.stdout, flush=True)

    def advance(self, text: str, error: bool = False) -> None:
        """One unit done: the bar moves (an error's ``text`` is printed above it), or, with no
        bar, ``[i/N] text`` is printed."""
        self.count += 1
        if self.bar is not None:
            self.bar.update(1)
            if error:
                self.write(text, error=True)
        else:
            self.write(f"[{self.count}/{self.total}] {text}", error=error)

    def close(self) -> None:
        """End the bar (left on the terminal or removed, as ``leave`` says)."""
        if self.bar is not None:
            self.bar.close()
