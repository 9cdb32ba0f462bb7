"""Single-view training (paper section 6): ``python train.py [group=option ...] [key=value ...]``.

See configs/train.yaml for the commands and svr/train.py for what runs.
"""
from svr.train import main

if __name__ == "__main__":
    main()
