"""The family store and its typed records: the one layout of paths (:mod:`.layout`), the build config
(:mod:`.config`), the family state in ``family.json`` (:mod:`.state`), the samples and pairs
(:mod:`.samples`), the template (:mod:`.template`) and the networks (:mod:`.networks`)."""
