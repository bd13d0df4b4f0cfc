"""The scene: a log pile as data (:class:`~synth.scene.pile.PileSpec`: terrain, logs, rocks,
stumps, georeference; its versioned file), the terrain height field and the pile generator that
drops and settles logs in the physics world."""
