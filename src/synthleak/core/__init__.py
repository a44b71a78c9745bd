"""The bottom layer, below assets / scene / render: the data types every stage passes around (``types``), the
reader of any USD stage into them (``usd_read``) and the dataset contract (``dataset``: reading sequence folders
and ``index.json``). Nothing here imports a stage package or a renderer."""
