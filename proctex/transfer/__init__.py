"""The run-time transfer: the template ready for transfer (:mod:`.assets`), the assignment of a new
shape's parts to the template's groups (:mod:`.assign`), the maps onto the template
(:mod:`.mappers`), the UV lookup (:mod:`.uvlookup`) and the transfer and bake (:mod:`.apply`), with
bounds on the work (:mod:`.budget`). Reads the store's records only."""
