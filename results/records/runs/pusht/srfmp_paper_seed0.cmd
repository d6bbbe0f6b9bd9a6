OMP_NUM_THREADS=1 .venv/bin/python recipes/pusht/train.py algo=srfmp obs=state space=euclidean threads=1 optim.lr=0.0001 train.steps=8000 train.max_minutes=150 out_dir=runs/pusht/srfmp_paper_seed0
