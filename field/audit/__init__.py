"""Tamper-evident records: the controller journal and trial records, hash-chained.

:mod:`field.audit.chain` is the chained JSON-lines file (canonical serialisation, sha256, append
and check); :mod:`field.audit.journal` and :mod:`field.audit.record` chain the controller's
journal and a trial record; :func:`field.audit.report.verify` is ``loggrasp audit verify``.
"""
