"""The use cases of the commands, one module each; the command line (or another front
end) parses what the user asked, calls one of them, and shows what it returns.

A use case takes a small frozen request of plain values, opens the source, builds the
filter and its consumers, runs, writes its outputs whole or not at all
(:mod:`ekfviz.io.files`), and returns a result: tables, verdicts, the report, where its
recording went. It prints nothing: it tells a :class:`~ekfviz.app.reporting.Reporter`
what it chose and warns of as it goes, and ends with one of ekfviz's own errors
(:mod:`ekfviz.app.errors`) when it cannot go on.

- :mod:`.replay` -- a log through a filter into a recording (its run: :mod:`.replaying`,
  the filter's set-up for its source: :mod:`.scans`);
- :mod:`.check` -- a filter in lockstep with the reference;
- :mod:`.class_grade` -- a class's submissions graded (one submission: :mod:`.grade`; in
  Gradescope's layout: :mod:`.gradescope`);
- :mod:`.compare`, :mod:`.sweep` -- studies of several runs (:mod:`.study`);
- :mod:`.consistency` -- Monte-Carlo consistency on a simulated scenario;
- :mod:`.calibrate` -- a log's noise estimated from its truth;
- :mod:`.simulate`, :mod:`.convert` -- logs written;
- :mod:`.info`, :mod:`.export` -- recordings read back;
- :mod:`.inputs`, :mod:`.settings`, :mod:`.scenarios`, :mod:`.outputs` -- what the use
  cases share: the input opened, the options as values, where outputs go;
- :mod:`.session` -- how a command runs in this process.
"""
