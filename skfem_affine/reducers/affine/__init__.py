"""Affinification and rigidification: the oracle, clustering, the mapping G of a frame (with its
body kind) and the two reducers on their shared frame flow (:mod:`.clustered`)."""
