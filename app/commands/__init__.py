"""One module per ``rangereg`` subcommand: its body and its printed output. Each has ``run(args) -> int``;
the parser and the dispatch live in :mod:`app.cli`."""
