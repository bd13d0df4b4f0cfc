"""The training data: rule-based candidate grasps (:mod:`.candidates`, Algorithm 1), grasp maps
(:mod:`.maps`), the grasp-map data set and its shards (:mod:`.dataset`), the compact committed
grasp store (:mod:`.datastore`) and the ``synth piles`` job (:mod:`.jobs`)."""
