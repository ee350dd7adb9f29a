"""File formats: BVH (:mod:`.bvh`) and glTF 2.0 / GLB characters (:mod:`.gltf`)."""
