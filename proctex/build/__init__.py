"""The build, stage by stage (docs/architecture.md): ``sample`` -> ``template`` -> ``paint`` -> ``pairs`` ->
``train`` -> ``evaluate``, one module each, as plans (:mod:`.plan`) an executor runs in this process
or on Ray (:mod:`.pipeline`)."""
