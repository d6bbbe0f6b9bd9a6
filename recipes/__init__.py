"""The training and evaluation recipes; `recipes.common` holds what every task recipe shares."""
