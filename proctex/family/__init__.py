"""Family: a built family and everything done with it.

``config`` (the build config), ``store`` (the store and its one layout), ``sources`` (where shapes
come from), ``template`` (the stored template record), ``stages`` and ``pipeline`` (the build),
``assets`` / ``assign`` / ``mappers`` / ``uvlookup`` / ``transfer`` (the run-time path), ``edits``,
``fidelity`` / ``evaluate`` (measuring) and ``service`` (serving). The top of the library: nothing in
``proctex`` but ``cli`` and ``demo`` imports it.
"""
