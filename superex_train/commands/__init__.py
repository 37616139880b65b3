"""``superex`` commands contributed by the train extra (entry-point group ``superex.commands``)."""
