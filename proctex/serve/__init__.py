"""Serving built families: one loaded family (:mod:`.service`), many of them by name
(:mod:`.catalog`) and persisted texture edits (:mod:`.edits`)."""
