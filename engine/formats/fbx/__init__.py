"""FBX: the document tree (:mod:`.nodes`) and its binary form (:mod:`.binary`)."""
