"""Project-wide pieces every loggrasp package uses, written once, at the bottom of the tree.

=====================  ===========================================================================
:mod:`.files`          atomic writes (bytes and text, umask-respecting), sha256 of a file, strict JSON
:mod:`.formats`        :class:`VersionedJson`: the one reader/writer of versioned JSON files
:mod:`.ranges`         :func:`parse_range`: ``'A-B'`` / ``'A'`` command-line ranges
:mod:`.processes`      :func:`exit_with_parent`: worker processes that die with their parent
:mod:`.runner`         :func:`run_tasks`: the one job runner (in-process, process pool, Dask), keyed results
:mod:`.errors`         :class:`LoggraspError`, the root of every package's error tree
:mod:`.cli`            what every package's command module shares (flags, errors as one line, output);
                       only command modules import it
=====================  ===========================================================================

Only the standard library and numpy are imported here (no pybullet, torch; typer only in
:mod:`.cli`, Dask only when the runner's ``dask`` engine runs), so every package, CLI and worker can use these cheaply.
"""
