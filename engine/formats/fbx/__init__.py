"""FBX: the document tree (:mod:`.nodes`), its binary (:mod:`.binary`) and ASCII (:mod:`.ascii`)
forms, and the scene read from it as a character with its takes (:mod:`.scene`)."""
