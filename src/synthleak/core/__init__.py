"""The bottom layer, below assets / scene / render: the data types every stage passes around (``types``) and
the reader of any USD stage into them (``usd_read``). Nothing here imports a stage package or a renderer."""
